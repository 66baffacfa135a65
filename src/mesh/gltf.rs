//! The glTF document: container, JSON, buffers and accessors, read defensively.
//!
//! Every index and length in an upload is hostile until checked: counts are capped
//! before anything is allocated, and offsets are checked with overflow-safe arithmetic
//! against the bytes that actually exist (never against a `byteLength` the file claims).

use super::{Limits, MeshError};
use base64::Engine;
use serde::Deserialize;
use serde_json::Value;

const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct Root {
    pub asset: Asset,
    pub scene: Option<usize>,
    pub scenes: Vec<Scene>,
    pub nodes: Vec<Node>,
    pub meshes: Vec<MeshDef>,
    pub accessors: Vec<Accessor>,
    pub buffer_views: Vec<BufferView>,
    pub buffers: Vec<Buffer>,
    pub skins: Vec<Skin>,
    pub images: Vec<Image>,
    pub extensions_used: Vec<String>,
    pub extensions_required: Vec<String>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default)]
pub struct Asset {
    pub version: String,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default)]
pub struct Scene {
    pub nodes: Vec<usize>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default)]
pub struct Node {
    pub name: Option<String>,
    pub children: Vec<usize>,
    pub mesh: Option<usize>,
    pub skin: Option<usize>,
    pub matrix: Option<[f32; 16]>,
    pub translation: Option<[f32; 3]>,
    pub rotation: Option<[f32; 4]>,
    pub scale: Option<[f32; 3]>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default)]
pub struct MeshDef {
    pub name: Option<String>,
    pub primitives: Vec<Primitive>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default)]
pub struct Primitive {
    pub attributes: std::collections::BTreeMap<String, usize>,
    pub indices: Option<usize>,
    pub mode: Option<u32>,
    pub extensions: Option<serde_json::Map<String, Value>>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct Accessor {
    pub buffer_view: Option<usize>,
    pub byte_offset: u64,
    pub component_type: u32,
    pub normalized: bool,
    pub count: u64,
    #[serde(rename = "type")]
    pub kind: String,
    pub sparse: Option<Sparse>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct Sparse {
    pub count: u64,
    pub indices: SparseIndices,
    pub values: SparseValues,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct SparseIndices {
    pub buffer_view: usize,
    pub byte_offset: u64,
    pub component_type: u32,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct SparseValues {
    pub buffer_view: usize,
    pub byte_offset: u64,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct BufferView {
    pub buffer: usize,
    pub byte_offset: u64,
    pub byte_length: u64,
    pub byte_stride: Option<u64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct Buffer {
    pub uri: Option<String>,
    pub byte_length: u64,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct Skin {
    pub inverse_bind_matrices: Option<usize>,
    pub joints: Vec<usize>,
    pub skeleton: Option<usize>,
    pub name: Option<String>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct Image {
    pub uri: Option<String>,
}

/// A parsed glTF: the raw JSON (kept whole so export preserves what we do not model),
/// the typed view we read geometry through, and every buffer's bytes.
#[derive(Debug)]
pub struct Document {
    pub json: Value,
    pub root: Root,
    pub buffers: Vec<Vec<u8>>,
}

pub fn is_glb(bytes: &[u8]) -> bool {
    bytes.len() >= 4 && &bytes[..4] == GLB_MAGIC
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    b.get(at..at.checked_add(4)?)
        .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

/// Splits a GLB into its JSON chunk and optional BIN chunk, trusting no length field.
pub fn parse_glb(bytes: &[u8], limits: &Limits) -> Result<Document, MeshError> {
    let bad = |m: &str| MeshError::Container(m.to_string());
    if bytes.len() < 12 {
        return Err(bad("shorter than the 12-byte header"));
    }
    if !is_glb(bytes) {
        return Err(bad("wrong magic"));
    }
    let version = u32_at(bytes, 4).unwrap_or(0);
    if version != 2 {
        return Err(MeshError::UnsupportedVersion(format!(
            "GLB container {version}"
        )));
    }
    let declared = u32_at(bytes, 8).unwrap_or(0) as usize;
    if declared > bytes.len() {
        return Err(bad("header length is longer than the file (truncated?)"));
    }
    let body = &bytes[..declared];
    let mut at = 12usize;
    let mut json_chunk: Option<&[u8]> = None;
    let mut bin_chunk: Option<&[u8]> = None;
    while at < body.len() {
        let len = u32_at(body, at).ok_or_else(|| bad("truncated chunk header"))? as usize;
        let kind = u32_at(body, at + 4).ok_or_else(|| bad("truncated chunk header"))?;
        let start = at + 8;
        let end = start
            .checked_add(len)
            .filter(|&e| e <= body.len())
            .ok_or_else(|| bad("chunk length runs past the end of the file"))?;
        match kind {
            CHUNK_JSON if json_chunk.is_none() && at == 12 => json_chunk = Some(&body[start..end]),
            CHUNK_JSON => return Err(bad("a second or misplaced JSON chunk")),
            CHUNK_BIN if bin_chunk.is_none() => bin_chunk = Some(&body[start..end]),
            CHUNK_BIN => return Err(bad("a second BIN chunk")),
            // Unknown chunk types must be ignored by readers (glTF 2.0 §4.4.3).
            _ => {}
        }
        // Chunks are 4-byte aligned; a misaligned length is tolerated by padding.
        at = end
            .checked_add((4 - len % 4) % 4)
            .ok_or_else(|| bad("length overflow"))?;
    }
    let json = json_chunk.ok_or_else(|| bad("no JSON chunk"))?;
    parse_document(json, bin_chunk, limits)
}

/// Parses glTF JSON; `bin` is the GLB BIN chunk, used by a buffer without a `uri`.
pub fn parse_document(
    json_bytes: &[u8],
    bin: Option<&[u8]>,
    limits: &Limits,
) -> Result<Document, MeshError> {
    let json = super::json::parse(json_bytes)?;
    if !json.is_object() {
        return Err(MeshError::Json("the top level is not an object".into()));
    }
    if !json
        .get("asset")
        .is_some_and(|a| a.get("version").is_some_and(Value::is_string))
    {
        return Err(MeshError::MissingAsset);
    }
    // Deserialised from a borrow: a clone of the tree would double the peak memory
    // of a JSON-heavy upload.
    let root = Root::deserialize(&json).map_err(|e| MeshError::Invalid(e.to_string()))?;
    check_shape(&json, root.buffers.len())?;
    if !root.asset.version.starts_with("2.") {
        return Err(MeshError::UnsupportedVersion(root.asset.version.clone()));
    }
    super::conform::check(&root)?;
    // Image URIs are left untouched and never fetched: geometry does not need them, and
    // an export that keeps the relative name lets the user keep the texture beside it.
    // Only absolute remote URIs are refused, since keeping them would point clients at
    // a host of the uploader's choosing.
    for img in &root.images {
        if let Some(uri) = &img.uri {
            if uri.contains("://") {
                return Err(MeshError::ExternalUri(uri.chars().take(200).collect()));
            }
        }
    }
    let mut buffers = Vec::with_capacity(root.buffers.len().min(64));
    let mut total: u64 = 0;
    for (i, buf) in root.buffers.iter().enumerate() {
        let data = match &buf.uri {
            // Filled by decoding (see `super::meshopt`); counted against the cap first.
            None if super::meshopt::is_fallback(&json, i) => {
                if total.saturating_add(buf.byte_length) > limits.max_bytes {
                    return Err(MeshError::TooLarge {
                        size: total.saturating_add(buf.byte_length),
                        cap: limits.max_bytes,
                    });
                }
                vec![0; buf.byte_length as usize]
            }
            None if i == 0 => bin
                .ok_or_else(|| {
                    MeshError::Invalid("buffer 0 has no uri and there is no BIN chunk".into())
                })?
                .to_vec(),
            None => return Err(MeshError::Invalid(format!("buffer {i} has no uri"))),
            Some(uri) => decode_data_uri(uri, limits)?,
        };
        if (data.len() as u64) < buf.byte_length {
            return Err(MeshError::Invalid(format!(
                "buffer {i} claims {} bytes but holds {}",
                buf.byte_length,
                data.len()
            )));
        }
        total += data.len() as u64;
        if total > limits.max_bytes {
            return Err(MeshError::TooLarge {
                size: total,
                cap: limits.max_bytes,
            });
        }
        buffers.push(data);
    }
    decompress(json, root, buffers, limits)
}

/// Decodes meshopt views and Draco primitives into the document (see `super::meshopt`
/// and `super::draco`), so that what is read and exported is a plain glTF.
fn decompress(
    mut json: Value,
    root: Root,
    mut buffers: Vec<Vec<u8>>,
    limits: &Limits,
) -> Result<Document, MeshError> {
    let meshopt = super::meshopt::used(&json);
    let draco = super::draco::used(&json);
    if !meshopt && !draco {
        return Ok(Document {
            json,
            root,
            buffers,
        });
    }
    drop(root);
    // meshopt first: a Draco stream may sit in a meshopt-compressed view.
    if meshopt {
        super::meshopt::decode(&mut json, &mut buffers)?;
    }
    if draco {
        super::draco::decode(&mut json, &mut buffers, limits)?;
    }
    let gone: &[&str] = &[
        super::draco::NAME,
        super::meshopt::NAMES[0],
        super::meshopt::NAMES[1],
    ];
    for key in ["extensionsUsed", "extensionsRequired"] {
        if let Some(list) = json.get_mut(key).and_then(Value::as_array_mut) {
            list.retain(|e| !e.as_str().is_some_and(|e| gone.contains(&e)));
            if list.is_empty() {
                json.as_object_mut().map(|o| o.remove(key));
            }
        }
    }
    let root = Root::deserialize(&json).map_err(|e| MeshError::Invalid(e.to_string()))?;
    check_shape(&json, root.buffers.len())?;
    super::conform::check(&root)?;
    Ok(Document {
        json,
        root,
        buffers,
    })
}

/// glTF's top-level arrays that hold objects, each of which an export copies.
const OBJECT_ARRAYS: [&str; 13] = [
    "accessors",
    "animations",
    "buffers",
    "bufferViews",
    "cameras",
    "images",
    "materials",
    "meshes",
    "nodes",
    "samplers",
    "scenes",
    "skins",
    "textures",
];

/// What the schema requires and serde's defaults would paper over: `[]` reads as an
/// empty object, a bufferView without `buffer` as one on buffer 0. An entry nothing
/// refers to passes the loader either way, but the export copies every entry of the
/// document, so such a file used to fail its job after inference instead of at upload.
fn check_shape(json: &Value, buffers: usize) -> Result<(), MeshError> {
    for key in OBJECT_ARRAYS {
        let Some(v) = json.get(key) else { continue };
        let a = v
            .as_array()
            .ok_or_else(|| MeshError::Invalid(format!("{key} is not an array")))?;
        if let Some(i) = a.iter().position(|e| !e.is_object()) {
            return Err(MeshError::Invalid(format!("{key}[{i}] is not an object")));
        }
    }
    let views = json.get("bufferViews").and_then(Value::as_array);
    for (i, v) in views.into_iter().flatten().enumerate() {
        let b = v
            .get("buffer")
            .and_then(Value::as_u64)
            .ok_or_else(|| MeshError::Invalid(format!("bufferView {i} has no buffer")))?;
        if b >= buffers as u64 {
            return Err(MeshError::IndexOutOfRange {
                what: "buffer",
                index: b,
            });
        }
    }
    Ok(())
}

/// Decodes a base64 `data:` URI. The decoded size is checked from the text length
/// before decoding, so a "data-URI bomb" is refused without being expanded.
fn decode_data_uri(uri: &str, limits: &Limits) -> Result<Vec<u8>, MeshError> {
    let Some(rest) = uri.strip_prefix("data:") else {
        return Err(MeshError::ExternalUri(uri.chars().take(200).collect()));
    };
    let (meta, payload) = rest
        .split_once(',')
        .ok_or_else(|| MeshError::Invalid("data: URI without a comma".into()))?;
    if !meta.ends_with(";base64") {
        return Err(MeshError::Invalid("data: URI that is not base64".into()));
    }
    let decoded_len = (payload.len() as u64 / 4) * 3;
    if decoded_len > limits.max_bytes {
        return Err(MeshError::TooLarge {
            size: decoded_len,
            cap: limits.max_bytes,
        });
    }
    base64::engine::general_purpose::STANDARD
        .decode(payload.trim_end())
        .map_err(|e| MeshError::Invalid(format!("data: URI is not valid base64: {e}")))
}

/// Component layout of an accessor element.
pub(super) fn type_components(kind: &str) -> Option<usize> {
    Some(match kind {
        "SCALAR" => 1,
        "VEC2" => 2,
        "VEC3" => 3,
        "VEC4" => 4,
        "MAT2" => 4,
        "MAT3" => 9,
        "MAT4" => 16,
        _ => return None,
    })
}

pub(super) fn component_size(ct: u32) -> Option<usize> {
    Some(match ct {
        5120 | 5121 => 1,
        5122 | 5123 => 2,
        5125 | 5126 => 4,
        _ => return None,
    })
}

/// Reads one component as f64; `normalized` maps integers to [0,1] or [-1,1].
fn read_component(b: &[u8], ct: u32, normalized: bool) -> f64 {
    match ct {
        5120 => {
            let v = b[0] as i8 as f64;
            if normalized {
                (v / 127.0).max(-1.0)
            } else {
                v
            }
        }
        5121 => {
            let v = b[0] as f64;
            if normalized {
                v / 255.0
            } else {
                v
            }
        }
        5122 => {
            let v = i16::from_le_bytes([b[0], b[1]]) as f64;
            if normalized {
                (v / 32767.0).max(-1.0)
            } else {
                v
            }
        }
        5123 => {
            let v = u16::from_le_bytes([b[0], b[1]]) as f64;
            if normalized {
                v / 65535.0
            } else {
                v
            }
        }
        5125 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        _ => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
    }
}

impl Document {
    /// Bytes of a buffer view, bounds-checked against the real buffer.
    fn view_bytes(&self, view: usize) -> Result<(&[u8], Option<u64>), MeshError> {
        let v = self
            .root
            .buffer_views
            .get(view)
            .ok_or(MeshError::IndexOutOfRange {
                what: "bufferView",
                index: view as u64,
            })?;
        let buf = self
            .buffers
            .get(v.buffer)
            .ok_or(MeshError::IndexOutOfRange {
                what: "buffer",
                index: v.buffer as u64,
            })?;
        let end = v
            .byte_offset
            .checked_add(v.byte_length)
            .filter(|&e| e <= buf.len() as u64)
            .ok_or_else(|| MeshError::Invalid(format!("bufferView {view} runs past its buffer")))?;
        Ok((&buf[v.byte_offset as usize..end as usize], v.byte_stride))
    }

    /// glTF allows an accessor with no data (all zeros). For positions and indices that
    /// can only be useless, and it would let a tiny file claim a huge zeroed array.
    pub fn require_data(&self, index: usize) -> Result<(), MeshError> {
        match self.root.accessors.get(index) {
            Some(a) if a.buffer_view.is_none() && a.sparse.is_none() && a.count > 0 => {
                Err(MeshError::Invalid(format!(
                    "accessor {index} has no bufferView and no sparse values"
                )))
            }
            _ => Ok(()),
        }
    }

    /// Number of elements an accessor holds, checked against `cap` before any allocation.
    pub fn accessor_count(&self, index: usize) -> Result<u64, MeshError> {
        self.root
            .accessors
            .get(index)
            .map(|a| a.count)
            .ok_or(MeshError::IndexOutOfRange {
                what: "accessor",
                index: index as u64,
            })
    }

    fn accessor(&self, index: usize) -> Result<&Accessor, MeshError> {
        self.root
            .accessors
            .get(index)
            .ok_or(MeshError::IndexOutOfRange {
                what: "accessor",
                index: index as u64,
            })
    }

    /// Reads an accessor as a flat list of f64 components (`count × components`),
    /// applying `normalized` and sparse substitution. `cap` bounds the element count.
    pub fn read_accessor(&self, index: usize, cap: u64) -> Result<(Vec<f64>, usize), MeshError> {
        let a = self.accessor(index)?;
        let comps = type_components(&a.kind)
            .ok_or_else(|| MeshError::Invalid(format!("accessor {index} has type {:?}", a.kind)))?;
        let csize = component_size(a.component_type).ok_or_else(|| {
            MeshError::Invalid(format!(
                "accessor {index} has componentType {}",
                a.component_type
            ))
        })?;
        if a.count > cap {
            return Err(MeshError::TooManyVertices {
                count: a.count,
                cap,
            });
        }
        let count = a.count as usize;
        let elem = comps * csize;
        let mut out = vec![0f64; count * comps];
        if let Some(view) = a.buffer_view {
            let (bytes, stride) = self.view_bytes(view)?;
            let stride = stride.map(|s| s as usize).unwrap_or(elem);
            if stride < elem {
                return Err(MeshError::Invalid(format!(
                    "accessor {index}: byteStride smaller than an element"
                )));
            }
            let needed = if count == 0 {
                0
            } else {
                (a.byte_offset as u128) + (stride as u128) * (count as u128 - 1) + elem as u128
            };
            if needed > bytes.len() as u128 {
                return Err(MeshError::AccessorOutOfBounds(index));
            }
            let base = a.byte_offset as usize;
            for i in 0..count {
                let at = base + i * stride;
                for c in 0..comps {
                    let o = at + c * csize;
                    out[i * comps + c] =
                        read_component(&bytes[o..o + csize], a.component_type, a.normalized);
                }
            }
        }
        if let Some(sp) = &a.sparse {
            self.apply_sparse(index, a, sp, comps, csize, &mut out)?;
        }
        Ok((out, comps))
    }

    fn apply_sparse(
        &self,
        index: usize,
        a: &Accessor,
        sp: &Sparse,
        comps: usize,
        csize: usize,
        out: &mut [f64],
    ) -> Result<(), MeshError> {
        if sp.count > a.count {
            return Err(MeshError::Invalid(format!(
                "accessor {index}: sparse count exceeds count"
            )));
        }
        let n = sp.count as usize;
        let isize = component_size(sp.indices.component_type)
            .filter(|_| matches!(sp.indices.component_type, 5121 | 5123 | 5125))
            .ok_or_else(|| {
                MeshError::Invalid(format!("accessor {index}: bad sparse index type"))
            })?;
        let (ib, _) = self.view_bytes(sp.indices.buffer_view)?;
        let (vb, _) = self.view_bytes(sp.values.buffer_view)?;
        let ioff = sp.indices.byte_offset as u128;
        let voff = sp.values.byte_offset as u128;
        if ioff + (n * isize) as u128 > ib.len() as u128
            || voff + (n * comps * csize) as u128 > vb.len() as u128
        {
            return Err(MeshError::AccessorOutOfBounds(index));
        }
        for k in 0..n {
            let io = ioff as usize + k * isize;
            let target =
                read_component(&ib[io..io + isize], sp.indices.component_type, false) as u64;
            if target >= a.count {
                return Err(MeshError::IndexOutOfRange {
                    what: "sparse index",
                    index: target,
                });
            }
            for c in 0..comps {
                let vo = voff as usize + (k * comps + c) * csize;
                out[target as usize * comps + c] =
                    read_component(&vb[vo..vo + csize], a.component_type, a.normalized);
            }
        }
        Ok(())
    }

    /// Reads an accessor of unsigned integers (indices, joint indices).
    pub fn read_indices(&self, index: usize, cap: u64) -> Result<(Vec<u32>, usize), MeshError> {
        let a = self.accessor(index)?;
        if !matches!(a.component_type, 5121 | 5123 | 5125) {
            return Err(MeshError::Invalid(format!(
                "accessor {index} must hold unsigned integers, has componentType {}",
                a.component_type
            )));
        }
        // Normalized integers read as fractions, which truncate to index 0 or 1.
        if a.normalized {
            return Err(MeshError::Invalid(format!(
                "accessor {index} holds indices but is normalized"
            )));
        }
        let (vals, comps) = self.read_accessor(index, cap)?;
        Ok((vals.into_iter().map(|v| v as u32).collect(), comps))
    }
}
