//! The library's compact file form, the one committed as `models/library.bin`: the
//! surface samples are most of a library (512 points an entry), and as JSON text they
//! made the 140-rig library 3 MB. Here they are 16-bit fixed point (box coordinates lie
//! in [-1, 1], so a step is 3e-5 of the box, far under any distance the ranking
//! separates), and everything else stays JSON so the skeletons keep their exact floats.
//!
//! Layout: `RSLB`, the format version (u32 LE), the header's length (u32 LE), the JSON
//! header (the library's version and, per entry, name, category, proportions, skeleton
//! and sample count), then every entry's samples in order as `i16` LE triples.

use super::{Entry, Library};
use crate::rig::Skeleton;
use glam::Vec3;
use serde::{Deserialize, Serialize};

pub const MAGIC: &[u8; 4] = b"RSLB";
const FORMAT: u32 = 1;
const SCALE: f32 = 32767.0;
/// A header past this is not a library this build wrote (140 rigs take about 300 KB).
const MAX_HEADER: usize = 64 << 20;

#[derive(Serialize, Deserialize)]
struct Header {
    version: u32,
    entries: Vec<EntryHeader>,
}

#[derive(Serialize, Deserialize)]
struct EntryHeader {
    name: String,
    category: String,
    proportions: Vec3,
    skeleton: Skeleton,
    points: usize,
}

pub fn encode(lib: &Library) -> Vec<u8> {
    let header = Header {
        version: lib.version,
        entries: lib
            .entries
            .iter()
            .map(|e| EntryHeader {
                name: e.name.clone(),
                category: e.category.clone(),
                proportions: e.proportions,
                skeleton: e.skeleton.clone(),
                points: e.points.len(),
            })
            .collect(),
    };
    let json = serde_json::to_vec(&header).expect("a library serializes");
    let mut out = Vec::with_capacity(12 + json.len() + 6 * lib.entries.len() * 512);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT.to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(&json);
    for e in &lib.entries {
        for p in &e.points {
            for c in p.to_array() {
                let q = (c.clamp(-1.0, 1.0) * SCALE).round() as i16;
                out.extend_from_slice(&q.to_le_bytes());
            }
        }
    }
    out
}

/// Why bytes are not a library file; the caller names the file.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    #[error("{0}")]
    Malformed(String),
    #[error(transparent)]
    Header(#[from] serde_json::Error),
}

pub fn decode(bytes: &[u8]) -> Result<Library, DecodeError> {
    let bad = |why: &str| DecodeError::Malformed(why.to_string());
    let u32_at = |at: usize| -> Result<u32, DecodeError> {
        bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes(b.try_into().expect("four bytes")))
            .ok_or_else(|| bad("truncated before the header"))
    };
    if bytes.get(..4) != Some(MAGIC.as_slice()) {
        return Err(bad("not a library file"));
    }
    let format = u32_at(4)?;
    if format != FORMAT {
        return Err(DecodeError::Malformed(format!(
            "file format {format}, this build reads {FORMAT}"
        )));
    }
    let len = u32_at(8)? as usize;
    if len > MAX_HEADER || 12 + len > bytes.len() {
        return Err(bad("header length runs past the file"));
    }
    let header: Header = serde_json::from_slice(&bytes[12..12 + len])?;
    let mut rest = &bytes[12 + len..];
    let mut entries = Vec::with_capacity(header.entries.len());
    for h in header.entries {
        let need = h
            .points
            .checked_mul(6)
            .filter(|&n| n <= rest.len())
            .ok_or_else(|| bad("samples run past the file"))?;
        let (mine, tail) = rest.split_at(need);
        rest = tail;
        let points = mine
            .chunks_exact(6)
            .map(|c| {
                let q = |i: usize| i16::from_le_bytes([c[i], c[i + 1]]) as f32 / SCALE;
                Vec3::new(q(0), q(2), q(4))
            })
            .collect();
        entries.push(Entry {
            name: h.name,
            category: h.category,
            proportions: h.proportions,
            points,
            skeleton: h.skeleton,
        });
    }
    if !rest.is_empty() {
        return Err(bad("bytes left after the last entry's samples"));
    }
    Ok(Library {
        version: header.version,
        entries,
    })
}
