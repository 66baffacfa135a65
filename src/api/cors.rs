//! Cross-origin access for browser front-ends on another origin (`serve --cors-origin`).
//! Off unless origins are listed. A listed origin may upload, follow SSE and download;
//! an unlisted one gets no `Access-Control-*` header at all, so its browser blocks the
//! page from reading anything, preflights included.

use axum::body::Body;
use axum::extract::State;
use axum::http::{header, HeaderName, HeaderValue, Method, Request};
use axum::middleware::Next;
use axum::response::Response;
use std::sync::Arc;
use std::time::Duration;
use tower_http::cors::{AllowOrigin, CorsLayer};

/// The allowed origins: any (`*`) or a list of exact `Origin` values.
#[derive(Clone, Debug)]
pub enum Origins {
    Any,
    List(Arc<Vec<HeaderValue>>),
}

#[derive(Debug, thiserror::Error)]
#[error("--cors-origin {0:?} is not an origin (scheme://host[:port], or *)")]
pub struct BadOrigin(pub String);

impl Origins {
    /// `None` when no origin is given: CORS stays off.
    pub fn parse(given: &[String]) -> Result<Option<Origins>, BadOrigin> {
        let given: Vec<&str> = given
            .iter()
            .flat_map(|g| g.split(','))
            .map(str::trim)
            .filter(|g| !g.is_empty())
            .collect();
        if given.is_empty() {
            return Ok(None);
        }
        if given.contains(&"*") {
            return Ok(Some(Origins::Any));
        }
        let list = given
            .iter()
            .map(|g| {
                // What browsers send: no path, no trailing slash.
                let g = g.trim_end_matches('/');
                let ok = (g.starts_with("http://") || g.starts_with("https://"))
                    && !g
                        .split_once("://")
                        .is_some_and(|(_, rest)| rest.contains('/'));
                ok.then(|| HeaderValue::from_str(g).ok())
                    .flatten()
                    .ok_or_else(|| BadOrigin(g.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Some(Origins::List(Arc::new(list))))
    }

    fn allows(&self, origin: Option<&HeaderValue>) -> bool {
        match (self, origin) {
            (Origins::Any, _) => true,
            (Origins::List(l), Some(o)) => l.contains(o),
            (Origins::List(_), None) => false,
        }
    }

    /// The layer answering preflights and adding the headers to listed origins' requests.
    pub fn layer(&self) -> CorsLayer {
        let allow = match self {
            Origins::Any => AllowOrigin::any(),
            Origins::List(l) => AllowOrigin::list(l.iter().cloned()),
        };
        CorsLayer::new()
            .allow_origin(allow)
            .allow_methods([Method::GET, Method::POST, Method::DELETE, Method::HEAD])
            .allow_headers([
                header::AUTHORIZATION,
                header::CONTENT_TYPE,
                header::ACCEPT,
                header::IF_NONE_MATCH,
                HeaderName::from_static("idempotency-key"),
                HeaderName::from_static("last-event-id"),
                HeaderName::from_static("x-request-id"),
            ])
            .expose_headers([
                header::LOCATION,
                header::RETRY_AFTER,
                header::ETAG,
                header::CONTENT_DISPOSITION,
                HeaderName::from_static("x-request-id"),
            ])
            .max_age(Duration::from_secs(600))
    }
}

/// Outside [`Origins::layer`]: the CORS layer still describes methods and headers to any
/// preflight; for an origin not listed, every `Access-Control-*` header is taken out.
pub async fn only_listed(
    State(origins): State<Origins>,
    req: Request<Body>,
    next: Next,
) -> Response {
    let allowed = origins.allows(req.headers().get(header::ORIGIN));
    let mut res = next.run(req).await;
    if !allowed {
        let names: Vec<HeaderName> = res
            .headers()
            .keys()
            .filter(|k| k.as_str().starts_with("access-control-"))
            .cloned()
            .collect();
        for n in names {
            res.headers_mut().remove(n);
        }
    }
    res
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origins_parse_lists_commas_and_wildcards() {
        assert!(Origins::parse(&[]).unwrap().is_none());
        assert!(Origins::parse(&["".into()]).unwrap().is_none());
        let o = Origins::parse(&["http://127.0.0.1:8099/, https://app.example".into()])
            .unwrap()
            .unwrap();
        assert!(o.allows(Some(&HeaderValue::from_static("http://127.0.0.1:8099"))));
        assert!(o.allows(Some(&HeaderValue::from_static("https://app.example"))));
        assert!(!o.allows(Some(&HeaderValue::from_static("http://127.0.0.1:8098"))));
        assert!(!o.allows(None));
        let any = Origins::parse(&["http://a.example".into(), "*".into()])
            .unwrap()
            .unwrap();
        assert!(any.allows(Some(&HeaderValue::from_static("http://b.example"))));
        for bad in ["127.0.0.1:8099", "http://a.example/page", "ftp://x"] {
            assert!(Origins::parse(&[bad.into()]).is_err(), "{bad}");
        }
    }
}
