//! The GLB container (glTF 2.0 §4.4): a 12-byte header, a JSON chunk, a BIN chunk.

use super::ExportError;
use serde_json::Value;

const MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// Serialises `json` and wraps it with `bin` (which buffer 0 must describe). Chunks are
/// padded to 4 bytes, JSON with spaces and BIN with zeros, as the format requires.
pub(crate) fn write_glb(json: &Value, bin: &[u8]) -> Result<Vec<u8>, ExportError> {
    let mut text = serde_json::to_vec(json)
        .map_err(|e| ExportError::Document(format!("JSON serialisation failed: {e}")))?;
    text.resize(text.len().next_multiple_of(4), b' ');
    let bin_padded = bin.len().next_multiple_of(4);
    let total = 12
        + 8
        + text.len() as u64
        + if bin.is_empty() {
            0
        } else {
            8 + bin_padded as u64
        };
    if total > u32::MAX as u64 {
        return Err(ExportError::TooLarge(total));
    }
    let mut out = Vec::with_capacity(total as usize);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(&CHUNK_JSON.to_le_bytes());
    out.extend_from_slice(&text);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin_padded as u32).to_le_bytes());
        out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
        out.extend_from_slice(bin);
        out.resize(total as usize, 0);
    }
    debug_assert_eq!(out.len() as u64, total);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_are_padded_and_lengths_add_up() {
        let json = serde_json::json!({"asset": {"version": "2.0"}, "x": "y"});
        let glb = write_glb(&json, &[1, 2, 3, 4, 5]).unwrap();
        let u32_at = |i: usize| u32::from_le_bytes(glb[i..i + 4].try_into().unwrap()) as usize;
        assert_eq!(&glb[..4], b"glTF");
        assert_eq!(u32_at(8), glb.len());
        let json_len = u32_at(12);
        assert_eq!(json_len % 4, 0);
        let text = std::str::from_utf8(&glb[20..20 + json_len]).unwrap();
        assert_eq!(
            serde_json::from_str::<Value>(text.trim_end()).unwrap(),
            json
        );
        let bin_at = 20 + json_len;
        assert_eq!(u32_at(bin_at), 8);
        assert_eq!(u32_at(bin_at + 4), CHUNK_BIN as usize);
        assert_eq!(&glb[bin_at + 8..], &[1, 2, 3, 4, 5, 0, 0, 0]);
    }
}
