//! What the glTF 2.0 specification forbids and a lenient reader would read anyway:
//! misaligned accessors, out-of-range strides, attribute types that need an extension
//! the file does not declare, and required extensions nobody here understands. Such a
//! file rigged "without complaint" gave garbage geometry (and `degenerate_mesh`) or a
//! result other tools refuse, so each gets its own code instead.

use super::gltf::{component_size, Root};
use super::MeshError;

/// Extensions a file may require: geometry rigserve decodes, or data it passes through
/// to the output untouched (materials, textures, lights, avatar metadata).
const UNDERSTOOD: &[&str] = &[
    "KHR_mesh_quantization",
    "KHR_draco_mesh_compression",
    "EXT_meshopt_compression",
    "KHR_meshopt_compression",
    "KHR_texture_transform",
    "KHR_texture_basisu",
    "EXT_texture_webp",
    "EXT_texture_avif",
    "KHR_lights_punctual",
    "KHR_materials_variants",
    "KHR_xmp_json_ld",
    "VRM",
];

/// Prefixes of families passed through as a whole.
const UNDERSTOOD_PREFIXES: &[&str] = &["KHR_materials_", "VRMC_"];

const FLOAT: u32 = 5126;

pub fn check(root: &Root) -> Result<(), MeshError> {
    for ext in &root.extensions_required {
        let known = UNDERSTOOD.contains(&ext.as_str())
            || UNDERSTOOD_PREFIXES.iter().any(|p| ext.starts_with(p));
        if !known {
            return Err(MeshError::UnsupportedRequiredExtension(ext.clone()));
        }
    }
    // A view that does not fit its buffer is refused, as `gltf_invalid`, when read;
    // alignment is only asked of the ones that do.
    let fits = |v: &super::gltf::BufferView| {
        root.buffers.get(v.buffer).is_some_and(|b| {
            v.byte_offset
                .checked_add(v.byte_length)
                .is_some_and(|end| end <= b.byte_length)
        })
    };
    for (i, v) in root.buffer_views.iter().enumerate() {
        // glTF 2.0 §5.11: byteStride is a multiple of 4 in [4, 252].
        if let Some(s) = v.byte_stride {
            if !(4..=252).contains(&s) || s % 4 != 0 {
                return Err(MeshError::BadByteStride(format!(
                    "bufferView {i} has byteStride {s}; glTF allows multiples of 4 from 4 to 252"
                )));
            }
        }
    }
    for (i, a) in root.accessors.iter().enumerate() {
        let Some(size) = component_size(a.component_type) else {
            continue; // refused with its index when read
        };
        let size = size as u64;
        let view = a.buffer_view.and_then(|v| root.buffer_views.get(v));
        if let Some(view) = view.filter(|v| fits(v)) {
            // §3.6.2.4: the accessor's offset, and its offset within the buffer, are
            // multiples of the component size (the stride, a multiple of 4, always is).
            let start = view.byte_offset.checked_add(a.byte_offset);
            if a.byte_offset % size != 0 || start.is_some_and(|o| o % size != 0) {
                return Err(MeshError::MisalignedAccessor(format!(
                    "accessor {i} starts at byte {} of its buffer, not a multiple of its \
                     {size}-byte component",
                    view.byte_offset.saturating_add(a.byte_offset)
                )));
            }
        }
        if let Some(sp) = &a.sparse {
            let pairs = [
                (
                    sp.indices.buffer_view,
                    sp.indices.byte_offset,
                    sp.indices.component_type,
                ),
                (
                    sp.values.buffer_view,
                    sp.values.byte_offset,
                    a.component_type,
                ),
            ];
            for (view, offset, ct) in pairs {
                let v = root.buffer_views.get(view).filter(|v| fits(v));
                let (Some(v), Some(size)) = (v, component_size(ct)) else {
                    continue;
                };
                if v.byte_offset
                    .checked_add(offset)
                    .is_some_and(|o| o % size as u64 != 0)
                {
                    return Err(MeshError::MisalignedAccessor(format!(
                        "accessor {i}'s sparse data is not aligned to its component size"
                    )));
                }
            }
        }
    }
    let quantized = root
        .extensions_used
        .iter()
        .any(|e| e == "KHR_mesh_quantization");
    for (m, mesh) in root.meshes.iter().enumerate() {
        for prim in &mesh.primitives {
            for (name, &acc) in &prim.attributes {
                let Some(a) = root.accessors.get(acc) else {
                    continue; // refused with its index when read
                };
                // §3.7.2.1: POSITION and NORMAL are floats; other types come with
                // KHR_mesh_quantization, which a file using them must declare.
                // Types that are no glTF type at all are refused when read.
                if matches!(name.as_str(), "POSITION" | "NORMAL")
                    && component_size(a.component_type).is_some()
                    && a.component_type != FLOAT
                    && !quantized
                {
                    return Err(MeshError::BadComponentType(format!(
                        "mesh {m}: {name} has componentType {} without KHR_mesh_quantization \
                         in extensionsUsed",
                        a.component_type
                    )));
                }
            }
            if let Some(a) = prim.indices.and_then(|i| root.accessors.get(i)) {
                if !matches!(a.component_type, 5121 | 5123 | 5125) {
                    return Err(MeshError::BadComponentType(format!(
                        "mesh {m}: indices have componentType {}; glTF allows unsigned \
                         byte, short or int",
                        a.component_type
                    )));
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn root(json: &str) -> Root {
        serde_json::from_str(json).unwrap()
    }

    const BASE: &str = r#""asset":{"version":"2.0"},"buffers":[{"byteLength":64}]"#;

    #[test]
    fn an_ordinary_document_passes() {
        let r = root(&format!(
            r#"{{{BASE},"bufferViews":[{{"buffer":0,"byteOffset":4,"byteLength":48,"byteStride":12}}],
            "accessors":[{{"bufferView":0,"byteOffset":0,"componentType":5126,"count":4,"type":"VEC3"}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "extensionsRequired":["KHR_materials_unlit","KHR_mesh_quantization"]}}"#
        ));
        assert_eq!(check(&r), Ok(()));
    }

    #[test]
    fn each_fault_has_its_code() {
        let cases = [
            (
                r#""bufferViews":[{"buffer":0,"byteOffset":2,"byteLength":48}],
                "accessors":[{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3"}]"#,
                "misaligned_accessor",
            ),
            (
                r#""bufferViews":[{"buffer":0,"byteLength":48}],
                "accessors":[{"bufferView":0,"byteOffset":1,"componentType":5123,"count":4,"type":"SCALAR"}]"#,
                "misaligned_accessor",
            ),
            (
                r#""bufferViews":[{"buffer":0,"byteLength":48,"byteStride":13}]"#,
                "bad_byte_stride",
            ),
            (
                r#""bufferViews":[{"buffer":0,"byteLength":48,"byteStride":256}]"#,
                "bad_byte_stride",
            ),
            (
                r#""extensionsRequired":["EXT_made_up"]"#,
                "unsupported_required_extension",
            ),
            (
                r#""bufferViews":[{"buffer":0,"byteLength":48}],
                "accessors":[{"bufferView":0,"componentType":5121,"count":4,"type":"VEC3"}],
                "meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}]"#,
                "unsupported_component_type",
            ),
        ];
        for (extra, code) in cases {
            let r = root(&format!("{{{BASE},{extra}}}"));
            assert_eq!(check(&r).map_err(|e| e.code()), Err(code), "{extra}");
        }
        // The same byte positions are fine once the extension is declared.
        let r = root(&format!(
            r#"{{{BASE},"extensionsUsed":["KHR_mesh_quantization"],
            "bufferViews":[{{"buffer":0,"byteLength":48}}],
            "accessors":[{{"bufferView":0,"componentType":5121,"count":4,"type":"VEC3"}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}]}}"#
        ));
        assert_eq!(check(&r), Ok(()));
    }
}
