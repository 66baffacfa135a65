use thiserror::Error;

/// Everything that can be wrong with an uploaded mesh. Each variant has a stable
/// `code()` that the API reports as `error_type` and failed jobs carry as their code.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum MeshError {
    #[error("the file is not a mesh format rigserve reads (GLB, glTF, VRM, OBJ, PLY or STL)")]
    UnknownFormat,
    #[error("the file is empty")]
    Empty,
    #[error("the file is {size} bytes, over the cap of {cap}")]
    TooLarge { size: u64, cap: u64 },
    #[error("GLB container: {0}")]
    Container(String),
    #[error("the glTF JSON does not parse: {0}")]
    Json(String),
    #[error("invalid glTF: {0}")]
    Invalid(String),
    #[error("{what} {index} is out of range")]
    IndexOutOfRange { what: &'static str, index: u64 },
    #[error("accessor {0} reads past the end of its buffer")]
    AccessorOutOfBounds(usize),
    #[error("external reference {0:?} refused: rigserve never fetches URIs; embed the data (GLB or data: URIs)")]
    ExternalUri(String),
    #[error("the extension {0} is not supported")]
    UnsupportedExtension(String),
    #[error("glTF version {0:?} is not supported (2.x only)")]
    UnsupportedVersion(String),
    #[error("no triangles: the file has only primitives of modes {0:?} (points or lines)")]
    NoTriangles(Vec<u32>),
    #[error("the scene has no meshes")]
    EmptyScene,
    #[error("{count} vertices, over the cap of {cap}")]
    TooManyVertices { count: u64, cap: u64 },
    #[error("{count} triangles, over the cap of {cap}")]
    TooManyTriangles { count: u64, cap: u64 },
    #[error("a vertex coordinate or transform is NaN or infinite")]
    NonFinite,
    #[error("the mesh has zero surface area")]
    Degenerate,
    #[error("the node hierarchy is not a tree: {0}")]
    BadHierarchy(String),
    #[error("OBJ line {line}: {msg}")]
    Obj { line: usize, msg: String },
    #[error("the glTF JSON holds more than {cap} values")]
    JsonTooComplex { cap: usize },
    #[error("a glTF JSON string or member name is {len} bytes, over the cap of {cap}")]
    StringTooLong { len: usize, cap: usize },
    #[error("the glTF JSON has no `asset` (glTF 2.0 requires one, with a version)")]
    MissingAsset,
    #[error("{0}")]
    MisalignedAccessor(String),
    #[error("{0}")]
    BadByteStride(String),
    #[error("the extension {0} is listed in extensionsRequired and rigserve does not read it")]
    UnsupportedRequiredExtension(String),
    #[error("{0}")]
    BadComponentType(String),
    #[error("compressed glTF data does not decode: {0}")]
    CompressedDataInvalid(String),
    #[error("PLY: {0}")]
    Ply(String),
    #[error("STL: {0}")]
    Stl(String),
}

impl MeshError {
    pub fn code(&self) -> &'static str {
        use MeshError::*;
        match self {
            UnknownFormat => "unknown_format",
            Empty => "empty_file",
            TooLarge { .. } => "file_too_large",
            Container(_) => "glb_malformed",
            Json(_) => "gltf_json_invalid",
            Invalid(_) => "gltf_invalid",
            IndexOutOfRange { .. } => "index_out_of_range",
            AccessorOutOfBounds(_) => "accessor_out_of_bounds",
            ExternalUri(_) => "external_uri",
            UnsupportedExtension(_) => "unsupported_extension",
            UnsupportedVersion(_) => "unsupported_version",
            NoTriangles(_) => "no_triangles",
            EmptyScene => "empty_scene",
            TooManyVertices { .. } => "too_many_vertices",
            TooManyTriangles { .. } => "too_many_triangles",
            NonFinite => "non_finite",
            Degenerate => "degenerate_mesh",
            BadHierarchy(_) => "bad_hierarchy",
            Obj { .. } => "obj_invalid",
            JsonTooComplex { .. } => "gltf_json_too_complex",
            StringTooLong { .. } => "gltf_string_too_long",
            MissingAsset => "missing_asset",
            MisalignedAccessor(_) => "misaligned_accessor",
            BadByteStride(_) => "bad_byte_stride",
            UnsupportedRequiredExtension(_) => "unsupported_required_extension",
            BadComponentType(_) => "unsupported_component_type",
            CompressedDataInvalid(_) => "compressed_data_invalid",
            Ply(_) => "ply_invalid",
            Stl(_) => "stl_invalid",
        }
    }
}
