//! Optional API keys. With a keys file, every `/v1` request needs `Authorization: Bearer
//! <key>`, and a job belongs to the key that created it: other keys get 404 for it, as if
//! it did not exist. Without one, all callers share the owner "".
//!
//! The file holds one key per line, `name:key` or a bare key (named by a hash prefix of
//! itself); blank lines and `#` comments are skipped. The name, never the key, is stored.

use super::error::ApiError;
use axum::extract::FromRequestParts;
use axum::http::request::Parts;
use axum::http::{header, StatusCode};
use sha2::{Digest, Sha256};
use std::collections::HashMap;
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum KeysError {
    #[error("reading API keys file {0}: {1}")]
    Read(String, std::io::Error),
    #[error("API keys file {0} holds no keys")]
    Empty(String),
}

#[derive(Clone, Debug, Default)]
pub struct ApiKeys {
    /// sha256(key) → owner name; `None` when auth is off.
    by_hash: Option<HashMap<[u8; 32], String>>,
}

fn digest(key: &str) -> [u8; 32] {
    Sha256::digest(key.as_bytes()).into()
}

impl ApiKeys {
    pub fn disabled() -> ApiKeys {
        ApiKeys { by_hash: None }
    }

    pub fn from_file(path: &Path) -> Result<ApiKeys, KeysError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| KeysError::Read(path.display().to_string(), e))?;
        let keys = ApiKeys::parse(&text);
        if keys.by_hash.as_ref().is_some_and(|m| m.is_empty()) {
            return Err(KeysError::Empty(path.display().to_string()));
        }
        Ok(keys)
    }

    pub fn parse(text: &str) -> ApiKeys {
        let mut map = HashMap::new();
        for line in text.lines().map(str::trim) {
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let (name, key) = match line.split_once(':') {
                Some((n, k)) if !n.trim().is_empty() => (n.trim().to_string(), k.trim()),
                _ => (format!("key-{}", &hex::encode(digest(line))[..12]), line),
            };
            if !key.is_empty() {
                map.insert(digest(key), name);
            }
        }
        ApiKeys { by_hash: Some(map) }
    }

    pub fn enabled(&self) -> bool {
        self.by_hash.is_some()
    }

    /// The owner for an `Authorization` header value.
    pub fn owner(&self, authorization: Option<&str>) -> Result<String, ApiError> {
        let Some(map) = &self.by_hash else {
            return Ok(String::new());
        };
        let unauthorized = |m: &str| ApiError::new(StatusCode::UNAUTHORIZED, "unauthorized", m);
        let token = authorization
            .and_then(|v| {
                v.strip_prefix("Bearer ")
                    .or_else(|| v.strip_prefix("bearer "))
            })
            .ok_or_else(|| unauthorized("an API key is required: Authorization: Bearer <key>"))?;
        map.get(&digest(token.trim()))
            .cloned()
            .ok_or_else(|| unauthorized("unknown API key"))
    }
}

/// The authenticated caller of a request.
#[derive(Clone, Debug)]
pub struct Caller {
    pub owner: String,
}

impl<S> FromRequestParts<S> for Caller
where
    S: Send + Sync,
    ApiKeys: axum::extract::FromRef<S>,
{
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Self::Rejection> {
        let keys = <ApiKeys as axum::extract::FromRef<S>>::from_ref(state);
        let auth = parts
            .headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok());
        Ok(Caller {
            owner: keys.owner(auth)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_and_owners() {
        let k = ApiKeys::parse("# team keys\nalice:sk-a\n\nsk-b\n");
        assert_eq!(k.owner(Some("Bearer sk-a")).unwrap(), "alice");
        let b = k.owner(Some("Bearer sk-b")).unwrap();
        assert!(b.starts_with("key-") && !b.contains("sk-b"));
        assert_eq!(k.owner(Some("Bearer nope")).unwrap_err().status, 401);
        assert_eq!(k.owner(None).unwrap_err().error_type, "unauthorized");
        assert_eq!(ApiKeys::disabled().owner(None).unwrap(), "");
    }
}
