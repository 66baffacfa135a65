//! `EXT_meshopt_compression` and `KHR_meshopt_compression`: buffer views whose bytes
//! are stored compressed elsewhere and decoded into the view's place.
//!
//! Decoder choice: the `meshopt` crate (MIT OR Apache-2.0), Rust bindings of
//! meshoptimizer, the library that defines the codec (its author wrote both extension
//! specifications, and gltfpack and gltf-transform encode with it). It bundles
//! meshoptimizer 1.3, which reads every vertex codec version either extension allows
//! (KHR's v1 included), builds from crates.io with the C++ compiler the machine already
//! has (no CMake, no network), and documents its decoders as safe on untrusted input (a
//! hostile stream decodes to garbage or an error code, never past the destination).
//! What it cannot check is what we pass in, so every count, stride and range is checked
//! here first: meshoptimizer asserts on a bad stride, which in a C++ release build means
//! undefined behaviour. Writing the codec again in Rust from the README was the
//! fallback; a port would have to be kept in step with the codec's new versions by hand.
//!
//! Decoding happens in the document itself: each compressed view's bytes are written
//! where the view points (usually into the `fallback` buffer, which has no data of its
//! own), the extension object is removed from the view and the buffer, and the
//! extension from `extensionsUsed`/`extensionsRequired`. The scene reader and the export
//! then see an ordinary uncompressed file, and the output GLB never declares a
//! compression whose data it does not carry. The compressed bytes stay in their buffer,
//! unreferenced.

use super::MeshError;
use serde_json::Value;

pub(super) const NAMES: [&str; 2] = ["EXT_meshopt_compression", "KHR_meshopt_compression"];

fn invalid(msg: impl Into<String>) -> MeshError {
    MeshError::CompressedDataInvalid(msg.into())
}

/// Whether buffer `i` is a meshopt fallback buffer (its bytes come from decoding).
pub(super) fn is_fallback(json: &Value, i: usize) -> bool {
    let ext = json
        .get("buffers")
        .and_then(|b| b.get(i))
        .and_then(|b| b.get("extensions"));
    NAMES.iter().any(|n| {
        ext.and_then(|e| e.get(*n))
            .and_then(|e| e.get("fallback"))
            .and_then(Value::as_bool)
            == Some(true)
    })
}

/// Whether any buffer view of the document is meshopt-compressed.
pub(super) fn used(json: &Value) -> bool {
    views(json).iter().any(|v| extension(v).is_some())
}

fn views(json: &Value) -> &[Value] {
    json.get("bufferViews")
        .and_then(Value::as_array)
        .map_or(&[], Vec::as_slice)
}

fn extension(view: &Value) -> Option<(&'static str, &Value)> {
    let exts = view.get("extensions")?;
    NAMES.iter().find_map(|n| exts.get(*n).map(|e| (*n, e)))
}

fn field(ext: &Value, view: usize, key: &str) -> Result<u64, MeshError> {
    ext.get(key).and_then(Value::as_u64).ok_or_else(|| {
        invalid(format!(
            "bufferView {view}: the meshopt extension has no valid {key}"
        ))
    })
}

/// Decodes every compressed view into place and strips the extension. `buffers` are
/// the document's buffers, fallback buffers already allocated at their byteLength.
pub(super) fn decode(json: &mut Value, buffers: &mut [Vec<u8>]) -> Result<(), MeshError> {
    let count = views(json).len();
    for i in 0..count {
        let view = &views(json)[i];
        let Some((name, ext)) = extension(view) else {
            continue;
        };
        let src_buffer = field(ext, i, "buffer")? as usize;
        let src_offset = ext.get("byteOffset").and_then(Value::as_u64).unwrap_or(0);
        let src_len = field(ext, i, "byteLength")?;
        let stride = field(ext, i, "byteStride")? as usize;
        let n = field(ext, i, "count")?;
        let mode = ext.get("mode").and_then(Value::as_str).unwrap_or("");
        let filter = ext.get("filter").and_then(Value::as_str).unwrap_or("NONE");
        let dst_buffer = view.get("buffer").and_then(Value::as_u64).unwrap_or(0) as usize;
        let dst_offset = view.get("byteOffset").and_then(Value::as_u64).unwrap_or(0);
        let dst_len = view.get("byteLength").and_then(Value::as_u64).unwrap_or(0);

        let src = buffers
            .get(src_buffer)
            .and_then(|b| {
                let end = src_offset.checked_add(src_len)?;
                b.get(src_offset as usize..usize::try_from(end).ok()?)
            })
            .ok_or_else(|| {
                invalid(format!(
                    "bufferView {i}: the compressed range runs past buffer {src_buffer}"
                ))
            })?;
        let size = n
            .checked_mul(stride as u64)
            .filter(|&s| s <= dst_len)
            .ok_or_else(|| {
                invalid(format!(
                    "bufferView {i}: {n} elements of {stride} bytes do not fit its {dst_len} bytes"
                ))
            })? as usize;
        let fits = buffers.get(dst_buffer).is_some_and(|b| {
            dst_offset
                .checked_add(size as u64)
                .is_some_and(|e| e <= b.len() as u64)
        });
        if !fits {
            return Err(invalid(format!(
                "bufferView {i}: the decoded data runs past buffer {dst_buffer}"
            )));
        }
        let out = decode_view(src, n as usize, stride, mode, filter, name)
            .map_err(|m| invalid(format!("bufferView {i}: {m}")))?;
        buffers[dst_buffer][dst_offset as usize..dst_offset as usize + size]
            .copy_from_slice(&out[..size]);
        if let Some(exts) = json["bufferViews"][i]
            .get_mut("extensions")
            .and_then(Value::as_object_mut)
        {
            exts.remove(name);
            if exts.is_empty() {
                json["bufferViews"][i]
                    .as_object_mut()
                    .map(|v| v.remove("extensions"));
            }
        }
    }
    // The fallback marker means nothing once the data is decoded.
    if let Some(bufs) = json.get_mut("buffers").and_then(Value::as_array_mut) {
        for b in bufs.iter_mut().filter_map(Value::as_object_mut) {
            if let Some(exts) = b.get_mut("extensions").and_then(Value::as_object_mut) {
                for n in NAMES {
                    exts.remove(n);
                }
                if exts.is_empty() {
                    b.remove("extensions");
                }
            }
        }
    }
    Ok(())
}

/// One view, decoded into a fresh 4-byte aligned buffer of at least `n * stride` bytes.
fn decode_view(
    src: &[u8],
    n: usize,
    stride: usize,
    mode: &str,
    filter: &str,
    name: &str,
) -> Result<Vec<u8>, String> {
    use meshopt::ffi;
    let size = n * stride;
    // u32 backing: the index decoders store 16- and 32-bit values through typed pointers.
    let mut words = vec![0u32; size.div_ceil(4)];
    let dst = words.as_mut_ptr().cast::<std::ffi::c_void>();
    let rc = match mode {
        "ATTRIBUTES" => {
            if stride == 0 || stride > 256 || !stride.is_multiple_of(4) {
                return Err(format!(
                    "ATTRIBUTES with byteStride {stride} (4 to 256, by 4)"
                ));
            }
            // SAFETY: `dst` holds n * stride bytes; stride is what the decoder accepts.
            unsafe { ffi::meshopt_decodeVertexBuffer(dst, n, stride, src.as_ptr(), src.len()) }
        }
        "TRIANGLES" | "INDICES" => {
            if stride != 2 && stride != 4 {
                return Err(format!("{mode} with byteStride {stride} (2 or 4)"));
            }
            if mode == "TRIANGLES" {
                if !n.is_multiple_of(3) {
                    return Err(format!(
                        "TRIANGLES with a count of {n}, not a multiple of 3"
                    ));
                }
                // SAFETY: as above; the count is a multiple of 3 and the size 2 or 4.
                unsafe { ffi::meshopt_decodeIndexBuffer(dst, n, stride, src.as_ptr(), src.len()) }
            } else {
                // SAFETY: as above.
                unsafe { ffi::meshopt_decodeIndexSequence(dst, n, stride, src.as_ptr(), src.len()) }
            }
        }
        other => return Err(format!("unknown mode {other:?}")),
    };
    if rc != 0 {
        return Err(format!(
            "the {mode} stream does not decode (meshoptimizer error {rc})"
        ));
    }
    if filter != "NONE" && mode != "ATTRIBUTES" {
        return Err(format!("filter {filter} on {mode} data"));
    }
    let ok = match filter {
        "NONE" => true,
        "OCTAHEDRAL" | "COLOR" => stride == 4 || stride == 8,
        "QUATERNION" => stride == 8,
        "EXPONENTIAL" => stride.is_multiple_of(4),
        other => return Err(format!("unknown filter {other:?}")),
    };
    if filter == "COLOR" && name != "KHR_meshopt_compression" {
        return Err("filter COLOR is KHR_meshopt_compression's, not EXT's".into());
    }
    if !ok {
        return Err(format!("filter {filter} with byteStride {stride}"));
    }
    // SAFETY: `dst` holds n elements of `stride` bytes, a stride each filter accepts.
    unsafe {
        match filter {
            "OCTAHEDRAL" => ffi::meshopt_decodeFilterOct(dst, n, stride),
            "QUATERNION" => ffi::meshopt_decodeFilterQuat(dst, n, stride),
            "EXPONENTIAL" => ffi::meshopt_decodeFilterExp(dst, n, stride),
            "COLOR" => ffi::meshopt_decodeFilterColor(dst, n, stride),
            _ => {}
        }
    }
    let mut bytes: Vec<u8> = words.iter().flat_map(|w| w.to_ne_bytes()).collect();
    bytes.truncate(size);
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn encoded_vertices(data: &[[u16; 2]]) -> Vec<u8> {
        meshopt::encoding::encode_vertex_buffer(data).unwrap()
    }

    #[test]
    fn a_view_decodes_into_the_fallback_buffer_and_the_extension_goes() {
        let verts: Vec<[u16; 2]> = (0..50u16).map(|i| [i, 1000 - i * 3]).collect();
        let enc = encoded_vertices(&verts);
        let mut json = json!({
            "buffers": [{"byteLength": enc.len()},
                        {"byteLength": 200, "extensions": {"EXT_meshopt_compression": {"fallback": true}}}],
            "bufferViews": [{"buffer": 1, "byteLength": 200, "byteStride": 4, "extensions": {
                "EXT_meshopt_compression": {"buffer": 0, "byteLength": enc.len(), "byteStride": 4,
                                            "count": 50, "mode": "ATTRIBUTES"}}}]
        });
        assert!(is_fallback(&json, 1) && !is_fallback(&json, 0) && used(&json));
        let mut buffers = vec![enc.clone(), vec![0; 200]];
        decode(&mut json, &mut buffers).unwrap();
        let back: Vec<u16> = buffers[1]
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        let want: Vec<u16> = verts.iter().flatten().copied().collect();
        assert_eq!(back, want);
        assert!(!used(&json));
        assert!(json["buffers"][1].get("extensions").is_none());
        assert!(json["bufferViews"][0].get("extensions").is_none());
    }

    #[test]
    fn bad_streams_and_parameters_are_typed_errors() {
        let verts: Vec<[u16; 2]> = (0..50u16).map(|i| [i, i]).collect();
        let enc = encoded_vertices(&verts);
        let case = |ext: Value, src: Vec<u8>| {
            let mut json = json!({
                "buffers": [{"byteLength": src.len()}, {"byteLength": 200}],
                "bufferViews": [{"buffer": 1, "byteLength": 200,
                                 "extensions": {"EXT_meshopt_compression": ext}}]
            });
            let mut buffers = vec![src, vec![0; 200]];
            decode(&mut json, &mut buffers).map_err(|e| e.code())
        };
        let base = json!({"buffer": 0, "byteLength": enc.len(), "byteStride": 4,
                          "count": 50, "mode": "ATTRIBUTES"});
        assert_eq!(case(base.clone(), enc.clone()), Ok(()));
        let mut flipped = enc.clone();
        for b in flipped.iter_mut().skip(1) {
            *b ^= 0x5a;
        }
        let with = |k: &str, v: Value| {
            let mut e = base.clone();
            e[k] = v;
            e
        };
        let code = Err("compressed_data_invalid");
        assert_eq!(case(base.clone(), flipped), code);
        assert_eq!(case(base.clone(), enc[..enc.len() / 2].to_vec()), code);
        assert_eq!(case(with("byteStride", json!(6)), enc.clone()), code);
        assert_eq!(case(with("count", json!(51)), enc.clone()), code);
        assert_eq!(case(with("count", json!(1u64 << 62)), enc.clone()), code);
        assert_eq!(case(with("byteLength", json!(1 << 20)), enc.clone()), code);
        assert_eq!(case(with("mode", json!("TRIANGLES")), enc.clone()), code);
        assert_eq!(case(with("mode", json!("SPLINES")), enc.clone()), code);
        assert_eq!(case(with("filter", json!("QUATERNION")), enc.clone()), code);
        assert_eq!(case(with("filter", json!("COLOR")), enc.clone()), code);
    }
}
