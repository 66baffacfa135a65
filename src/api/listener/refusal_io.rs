//! A connection that rewrites hyper's own bodiless refusals into the service's JSON.
//!
//! Every error response the router produces carries a JSON body
//! ([`crate::api::refusals::json_errors`] sees to the framework's own), so a `400`,
//! `414` or `431` head with `content-length: 0` on the wire can only be one hyper wrote
//! for a request it could not parse, after which it closes the connection. Such a head
//! is replaced whole by the same status with `{error, error_type}`; every other byte
//! passes through untouched. Vectored writes are declined so each head arrives in one
//! buffer.

use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

pub struct JsonRefusals<T> {
    inner: T,
    /// The replacement still to write, and how many bytes of the caller's buffer it
    /// stands for (reported once it is all written).
    pending: Option<(Vec<u8>, usize)>,
    /// Whether a line end has been read since the last response head was written: when
    /// hyper's buffer fills before the request line ends, its `431` is about the URL.
    line_ended: bool,
}

impl<T> JsonRefusals<T> {
    pub fn new(inner: T) -> Self {
        JsonRefusals {
            inner,
            pending: None,
            line_ended: false,
        }
    }
}

/// The JSON answer standing in for `head`, when `head` is one of hyper's refusals;
/// `in_url` when the request line had not ended (a `431` is then a `414`).
fn replacement(head: &[u8], in_url: bool) -> Option<Vec<u8>> {
    let text = std::str::from_utf8(head).ok()?;
    let (mut status_line, rest) = text.split_once("\r\n")?;
    let rest = rest
        .strip_suffix("\r\n\r\n")
        .or(rest.strip_suffix("\r\n"))?;
    let version = status_line.get(..8)?;
    let mut code = status_line.strip_prefix("HTTP/1.")?.get(2..5)?;
    let url_line = format!("{version} 414 URI Too Long");
    if code == "431" && in_url {
        code = "414";
        status_line = &url_line;
    }
    let (error_type, message) = match code {
        "400" => ("bad_request", "the request line or a header does not parse"),
        "414" => ("uri_too_long", "the URL is too long"),
        "431" => ("headers_too_large", "the request head is too large"),
        _ => return None,
    };
    let mut empty = false;
    let mut kept = Vec::new();
    for line in rest.split("\r\n").filter(|l| !l.is_empty()) {
        let (name, value) = line.split_once(':')?;
        match name.trim().to_ascii_lowercase().as_str() {
            "content-length" if value.trim() == "0" => empty = true,
            // A body of any kind means this is not hyper's bare refusal.
            "content-length" | "content-type" | "transfer-encoding" => return None,
            _ => kept.push(line),
        }
    }
    if !empty {
        return None;
    }
    let body = serde_json::json!({ "error": message, "error_type": error_type }).to_string();
    let mut out = format!(
        "{status_line}\r\ncontent-type: application/json\r\ncontent-length: {}\r\n",
        body.len()
    );
    for line in kept {
        out.push_str(line);
        out.push_str("\r\n");
    }
    out.push_str("\r\n");
    out.push_str(&body);
    Some(out.into_bytes())
}

/// Whether `buf` is exactly one response head with a 4xx status.
fn is_error_head(buf: &[u8]) -> bool {
    (buf.starts_with(b"HTTP/1.1 4") || buf.starts_with(b"HTTP/1.0 4"))
        && buf.ends_with(b"\r\n\r\n")
        && buf.windows(4).position(|w| w == b"\r\n\r\n") == Some(buf.len() - 4)
}

impl<T: AsyncRead + Unpin> AsyncRead for JsonRefusals<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        let r = Pin::new(&mut self.inner).poll_read(cx, buf);
        if buf.filled()[before..].contains(&b'\n') {
            self.line_ended = true;
        }
        r
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for JsonRefusals<T> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        if self.pending.is_none() && is_error_head(buf) {
            if let Some(r) = replacement(buf, !self.line_ended) {
                self.pending = Some((r, buf.len()));
            }
        }
        if self.pending.is_none() && buf.starts_with(b"HTTP/1.") {
            self.line_ended = false;
        }
        let this = &mut *self;
        let Some((bytes, stands_for)) = &mut this.pending else {
            return Pin::new(&mut this.inner).poll_write(cx, buf);
        };
        // hyper calls again with the same buffer after `Pending`, so the replacement is
        // written across calls and reported as the original's length at the end.
        while !bytes.is_empty() {
            match Pin::new(&mut this.inner).poll_write(cx, bytes) {
                Poll::Ready(Ok(0)) => return Poll::Ready(Err(io::ErrorKind::WriteZero.into())),
                Poll::Ready(Ok(n)) => {
                    bytes.drain(..n);
                }
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Pending => return Poll::Pending,
            }
        }
        let n = *stands_for;
        this.pending = None;
        Poll::Ready(Ok(n))
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    fn is_write_vectored(&self) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hypers_bare_refusal_becomes_json_and_nothing_else_changes() {
        let bare = b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-length: 0\r\ndate: Sun, 06 Dec 2026 19:00:00 GMT\r\n\r\n";
        assert!(is_error_head(bare));
        let out = String::from_utf8(replacement(bare, false).unwrap()).unwrap();
        let (head, body) = out.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 431 "));
        assert!(head.contains("content-type: application/json"));
        assert!(head.contains(&format!("content-length: {}", body.len())));
        assert!(head.contains("date: Sun"));
        let v: serde_json::Value = serde_json::from_str(body).unwrap();
        assert_eq!(v["error_type"], "headers_too_large");
        // The service's own errors have bodies; successes and other statuses pass.
        let own = b"HTTP/1.1 404 Not Found\r\ncontent-type: application/json\r\ncontent-length: 52\r\n\r\n";
        assert_eq!(replacement(own, false), None);
        assert_eq!(
            replacement(
                b"HTTP/1.1 204 No Content\r\ncontent-length: 0\r\n\r\n",
                false
            ),
            None
        );
        assert_eq!(
            replacement(
                b"HTTP/1.1 408 Request Timeout\r\ncontent-length: 0\r\n\r\n",
                false
            ),
            None
        );
        // A head that overflowed inside the request line was a URL too long.
        let url = String::from_utf8(replacement(bare, true).unwrap()).unwrap();
        assert!(url.starts_with("HTTP/1.1 414 URI Too Long\r\n"), "{url}");
        assert!(url.contains("uri_too_long"));
        assert!(!is_error_head(
            b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n{}"
        ));
    }
}
