//! Reading an upload: the mesh (raw body or the `file` part of a multipart form) streamed
//! to a temporary file under a byte cap, and the job options from the query string and an
//! optional `options` JSON part.

use super::error::ApiError;
use crate::jobs::JobOptions;
use crate::mesh::Format;
use axum::body::Body;
use axum::extract::{FromRequest, Multipart, Request};
use axum::http::{header, StatusCode};
use bytes::Bytes;
use futures_util::{Stream, StreamExt};
use serde_json::{Map, Value};
use std::path::Path;
use tokio::io::AsyncWriteExt;

/// Options part or query larger than this is refused: they are small by nature.
const MAX_OPTIONS_BYTES: usize = 1 << 20;

pub struct Upload {
    pub bytes: Bytes,
    /// The declared media type of the mesh (the part's type for multipart).
    pub content_type: Option<String>,
    pub filename: Option<String>,
    /// The `options` JSON part, when there is one.
    pub options: Option<Value>,
}

fn too_large(limit: u64) -> ApiError {
    ApiError::new(
        StatusCode::PAYLOAD_TOO_LARGE,
        "file_too_large",
        format!("the upload is larger than the limit of {limit} bytes"),
    )
}

fn media_type(v: &str) -> String {
    v.split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase()
}

/// Streams `chunks` into a temporary file in `tmp_dir`, refusing more than `limit` bytes,
/// and reads the whole file back.
async fn spool<S>(mut chunks: S, limit: u64, tmp_dir: &Path) -> Result<Bytes, ApiError>
where
    S: Stream<Item = Result<Bytes, ApiError>> + Unpin,
{
    let tmp = tempfile::NamedTempFile::new_in(tmp_dir).map_err(|e| {
        ApiError::new(
            StatusCode::INSUFFICIENT_STORAGE,
            "spool_failed",
            format!("cannot buffer the upload: {e}"),
        )
    })?;
    let io_err = |e: std::io::Error| {
        ApiError::new(
            StatusCode::INSUFFICIENT_STORAGE,
            "spool_failed",
            format!("cannot buffer the upload: {e}"),
        )
    };
    let mut file = tokio::fs::File::from_std(tmp.reopen().map_err(io_err)?);
    let mut total = 0u64;
    while let Some(chunk) = chunks.next().await {
        let chunk = chunk?;
        total += chunk.len() as u64;
        if total > limit {
            return Err(too_large(limit));
        }
        file.write_all(&chunk).await.map_err(io_err)?;
    }
    file.flush().await.map_err(io_err)?;
    drop(file);
    let bytes = tokio::fs::read(tmp.path()).await.map_err(io_err)?;
    Ok(Bytes::from(bytes))
}

/// Reads the request: multipart (`file` + optional `options`) or a raw body.
pub async fn read(req: Request<Body>, limit: u64, tmp_dir: &Path) -> Result<Upload, ApiError> {
    let declared = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(media_type);
    if let Some(len) = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
    {
        // Refuse before reading a byte when the client says how much is coming.
        if len
            > limit
                + if declared.as_deref() == Some("multipart/form-data") {
                    MAX_OPTIONS_BYTES as u64 + 65536
                } else {
                    0
                }
        {
            return Err(too_large(limit));
        }
    }
    if declared.as_deref() != Some("multipart/form-data") {
        // A wrong type is refused before a byte of the body is read.
        declared_format(declared.as_deref())?;
        let chunks = req
            .into_body()
            .into_data_stream()
            .map(|c| c.map_err(interrupted));
        let bytes = spool(chunks, limit, tmp_dir).await?;
        return Ok(Upload {
            bytes,
            content_type: declared,
            filename: None,
            options: None,
        });
    }
    let mut form = Multipart::from_request(req, &())
        .await
        .map_err(|e| ApiError::bad_request("multipart_invalid", e.body_text()))?;
    let mut upload = Upload {
        bytes: Bytes::new(),
        content_type: None,
        filename: None,
        options: None,
    };
    let mut have_file = false;
    loop {
        let field = match form.next_field().await {
            Ok(Some(f)) => f,
            Ok(None) => break,
            Err(e) => return Err(multipart_error(e, limit)),
        };
        match field.name() {
            Some("file") if !have_file => {
                upload.content_type = field.content_type().map(media_type);
                upload.filename = field.file_name().map(|s| s.chars().take(255).collect());
                let chunks = Box::pin(futures_util::stream::unfold(field, |mut f| async move {
                    match f.chunk().await {
                        Ok(Some(c)) => Some((Ok(c), f)),
                        Ok(None) => None,
                        Err(e) => Some((Err(multipart_error(e, limit)), f)),
                    }
                }));
                upload.bytes = spool(chunks, limit, tmp_dir).await?;
                have_file = true;
            }
            Some("options") => {
                let text = field.text().await.map_err(|e| multipart_error(e, limit))?;
                if text.len() > MAX_OPTIONS_BYTES {
                    return Err(ApiError::unprocessable(
                        "invalid_options",
                        "the options part is larger than 1 MiB",
                    ));
                }
                let v: Value = serde_json::from_str(&text).map_err(|e| {
                    ApiError::unprocessable("invalid_options", format!("options: {e}"))
                })?;
                upload.options = Some(v);
            }
            // Unknown parts are skipped (and not buffered).
            _ => {}
        }
    }
    if !have_file {
        return Err(ApiError::bad_request(
            "multipart_invalid",
            "the form has no `file` part",
        ));
    }
    Ok(upload)
}

fn interrupted(e: impl std::fmt::Display) -> ApiError {
    ApiError::bad_request("upload_interrupted", format!("reading the upload: {e}"))
}

/// The form's own fault (a missing closing boundary, broken part headers) is
/// `multipart_invalid`; the body failing to arrive (axum reports it as a 500: the
/// connection's fault, not the form's) is `upload_interrupted`.
fn multipart_error(e: axum::extract::multipart::MultipartError, limit: u64) -> ApiError {
    match e.status() {
        StatusCode::PAYLOAD_TOO_LARGE => too_large(limit),
        StatusCode::BAD_REQUEST => ApiError::bad_request("multipart_invalid", e.body_text()),
        _ => interrupted(e.body_text()),
    }
}

/// The format a declared media type promises; `Ok(None)` when the type leaves it to the
/// file's magic bytes.
pub fn declared_format(content_type: Option<&str>) -> Result<Option<Format>, ApiError> {
    match content_type {
        None | Some("") | Some("application/octet-stream") => Ok(None),
        Some("model/gltf-binary") | Some("model/vrm") => Ok(Some(Format::Glb)),
        Some("model/gltf+json") => Ok(Some(Format::Gltf)),
        Some("model/obj") | Some("application/x-tgif") => Ok(Some(Format::Obj)),
        // Text could be OBJ, ASCII PLY or ASCII STL: the magic decides.
        Some("text/plain") => Ok(None),
        Some("model/stl")
        | Some("application/sla")
        | Some("model/x.stl-binary")
        | Some("model/x.stl-ascii") => Ok(Some(Format::Stl)),
        Some("model/ply") | Some("application/ply") | Some("model/x-ply") => Ok(Some(Format::Ply)),
        Some(other) => Err(ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported_media_type",
            format!(
                "{other} is not a mesh type: send model/gltf-binary (GLB, VRM), \
                 model/gltf+json, model/obj, model/ply, model/stl, or application/octet-stream"
            ),
        )),
    }
}

/// Refuses a file whose magic says another format than its declared type.
pub fn check_magic(declared: Option<Format>, bytes: &[u8]) -> Result<(), ApiError> {
    let (Some(want), Some(got)) = (declared, crate::mesh::sniff(bytes)) else {
        // Unrecognizable files go on to the loader, which names what is wrong.
        return Ok(());
    };
    let same = want == got || (want == Format::Glb && got == Format::Vrm);
    if same {
        Ok(())
    } else {
        Err(ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "content_type_mismatch",
            format!("the body is {got:?} but the declared type says {want:?}"),
        ))
    }
}

/// Job options from query parameters, with the `options` JSON part laid over them.
pub fn options(query: Option<&str>, part: Option<Value>) -> Result<JobOptions, ApiError> {
    let bad = |m: String| ApiError::unprocessable("invalid_options", m);
    let mut map = Map::new();
    if let Some(q) = query {
        if q.len() > MAX_OPTIONS_BYTES {
            return Err(bad("the query string is larger than 1 MiB".into()));
        }
        for (k, v) in url::form_urlencoded::parse(q.as_bytes()) {
            let value = match k.as_ref() {
                "seed" | "samples" | "max_bones" => Value::from(
                    v.parse::<u64>()
                        .map_err(|_| bad(format!("{k} must be a non-negative integer")))?,
                ),
                "skin_only" => Value::from(match v.as_ref() {
                    "true" | "1" | "" => true,
                    "false" | "0" => false,
                    _ => return Err(bad("skin_only must be true or false".into())),
                }),
                "skeleton" => serde_json::from_str(&v)
                    .map_err(|e| bad(format!("skeleton is not JSON: {e}")))?,
                _ => Value::from(v.into_owned()),
            };
            map.insert(k.into_owned(), value);
        }
    }
    match part {
        Some(Value::Object(o)) => map.extend(o),
        Some(_) => return Err(bad("the options part must be a JSON object".into())),
        None => {}
    }
    serde_json::from_value(Value::Object(map)).map_err(|e| bad(format!("options: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::jobs::TemplateChoice;

    #[test]
    fn query_and_part_merge() {
        let o = options(
            Some("seed=7&template=mixamo&skin_only=false&category=quadruped&up=-z"),
            Some(serde_json::json!({"samples": 2, "category": "bird_flyer"})),
        )
        .unwrap();
        assert_eq!((o.seed, o.samples), (7, 2));
        assert_eq!(o.template, TemplateChoice::Mixamo);
        assert_eq!(
            o.up,
            crate::predict::orient::Up::Axis(crate::predict::orient::Axis::NegZ)
        );
        assert_eq!(o.category.as_deref(), Some("bird_flyer"));
        for q in [
            "seed=-1",
            "samples=x",
            "bogus=1",
            "template=maybe",
            "up=w",
            "skin_only=2",
        ] {
            let e = options(Some(q), None).unwrap_err();
            assert_eq!(e.error_type, "invalid_options", "{q}");
        }
    }

    #[test]
    fn media_types() {
        assert_eq!(declared_format(None).unwrap(), None);
        assert_eq!(
            declared_format(Some("model/gltf-binary")).unwrap(),
            Some(Format::Glb)
        );
        let e = declared_format(Some("image/png")).unwrap_err();
        assert_eq!(
            (e.status.as_u16(), e.error_type.as_str()),
            (415, "unsupported_media_type")
        );
        let e = check_magic(Some(Format::Gltf), b"glTF\x02\0\0\0").unwrap_err();
        assert_eq!(e.error_type, "content_type_mismatch");
        assert!(check_magic(Some(Format::Glb), b"garbage").is_ok());
    }
}
