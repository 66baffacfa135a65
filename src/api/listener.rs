//! The accept loop: axum's `serve`, with every connection's writes passed through
//! [`JsonRefusals`] so that what hyper refuses on its own leaves as the service's JSON.
//!
//! hyper answers a request line or header block it will not parse with a bare status
//! and no body: a request head over its buffer (about 400 KiB) `431`, a URL over 64 KiB
//! `414`, a malformed request line `400`. Those answers are written before any layer of
//! the router could see the request, so the only place to give them the service's
//! `{error, error_type}` body is the connection itself. Requests hyper does parse are
//! held to tighter limits by [`super::refusals`], which answers in JSON directly.
//!
//! Shutdown, as in axum: when `shutdown` fires no connection is accepted any more, each
//! open connection finishes its in-flight request and closes (HTTP/1 keep-alive off,
//! HTTP/2 GOAWAY), and the function returns once every connection is gone.

use axum::body::Body;
use axum::extract::Request;
use axum::Router;
use hyper::body::Incoming;
use hyper_util::rt::{TokioExecutor, TokioIo};
use hyper_util::server::conn::auto::Builder;
use hyper_util::service::TowerToHyperService;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tower::ServiceExt;
use tracing::{debug, warn};

mod refusal_io;
use refusal_io::JsonRefusals;

pub async fn serve(
    listener: TcpListener,
    router: Router,
    shutdown: CancellationToken,
) -> std::io::Result<()> {
    // Every connection task holds a clone; `closed()` resolves when the last is dropped.
    let (alive_tx, alive_rx) = tokio::sync::watch::channel(());
    loop {
        let (stream, peer) = tokio::select! {
            _ = shutdown.cancelled() => break,
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors and the like: wait instead of spinning,
                    // as axum does.
                    warn!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
        };
        let _ = stream.set_nodelay(true);
        let service = router
            .clone()
            .map_request(|req: Request<Incoming>| req.map(Body::new));
        let service = TowerToHyperService::new(service);
        let shutdown = shutdown.clone();
        let alive = alive_rx.clone();
        tokio::spawn(async move {
            let builder = Builder::new(TokioExecutor::new());
            let io = TokioIo::new(JsonRefusals::new(stream));
            let conn = builder.serve_connection_with_upgrades(io, service);
            let mut conn = std::pin::pin!(conn);
            tokio::select! {
                r = conn.as_mut() => {
                    if let Err(e) = r {
                        debug!(%peer, error = %e, "connection ended with an error");
                    }
                }
                _ = shutdown.cancelled() => {
                    conn.as_mut().graceful_shutdown();
                    if let Err(e) = conn.await {
                        debug!(%peer, error = %e, "connection ended with an error");
                    }
                }
            }
            drop(alive);
        });
    }
    drop(alive_rx);
    drop(listener);
    alive_tx.closed().await;
    Ok(())
}
