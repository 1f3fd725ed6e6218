//! The operator station's runtime and HTTP serving (issue 24).
//!
//! Every operator surface (status socket, metrics, web HMI, the DCS block) is served on a
//! tokio runtime of its own whose threads run at **ordinary priority** (`SCHED_OTHER`, set
//! explicitly at each thread's start: a thread inherits its creator's policy, and the bus
//! I/O threads run `SCHED_FIFO`). No client request reaches the control thread or a bus I/O
//! thread; [`HttpStats::realtime`] counts any request that was handled on a real-time thread
//! anyway (read from the handling thread with `sched_getscheduler(0)`), so a test can assert
//! that it stays zero.
//!
//! HTTP is hyper (HTTP/1.1 with keep-alive) under an axum router, with bounds on everything a
//! client controls: connections at once ([`HttpLimits::max_connections`]; at the cap a new
//! connection is closed at once), the request head (size and read time), the body, the time
//! a handler may take, and how long a connection may stay idle.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use axum::extract::Request;
use axum::response::{IntoResponse, Response};
use axum::Router;
use hyper::StatusCode;
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt};

/// Worker threads of the station runtime: two keep a slow request (a status report, a page)
/// from holding up the others on a two-core controller PC without taking it over.
pub const STATION_WORKER_THREADS: usize = 2;

/// Blocking threads of the station runtime (event-log tail reads, state file writes).
pub const STATION_BLOCKING_THREADS: usize = 4;

/// Bounds of one HTTP surface.
#[derive(Debug, Clone, Copy)]
pub struct HttpLimits {
    /// Connections served at once; more are closed as they arrive. A browser opens up to six
    /// per origin; 32 leave room for a few stations and scrapers.
    pub max_connections: usize,
    /// The request head must arrive within this (slow-header clients are dropped).
    pub head_timeout: Duration,
    /// A keep-alive connection with no traffic for this long is closed (the HMI polls every
    /// 2 s, so 15 s is seven missed polls).
    pub idle_timeout: Duration,
    /// A handler that takes longer answers 503 (a status report takes microseconds, an
    /// event-log tail read of 64 KiB a millisecond).
    pub handler_timeout: Duration,
    /// Largest request body, bytes (operator actions are a few words).
    pub max_body_bytes: usize,
    /// Read buffer, bytes: bounds the request head (hyper's minimum is 8 KiB).
    pub max_buf_bytes: usize,
}

impl Default for HttpLimits {
    fn default() -> Self {
        HttpLimits {
            max_connections: 32,
            head_timeout: Duration::from_secs(5),
            idle_timeout: Duration::from_secs(15),
            handler_timeout: Duration::from_secs(2),
            max_body_bytes: 1024,
            max_buf_bytes: 16 * 1024,
        }
    }
}

/// What the HTTP surfaces served (process-wide; exposed on the metrics endpoint and in the
/// HMI's `/api/status` under `station`).
#[derive(Debug, Default)]
pub struct HttpStats {
    /// Requests handled.
    pub requests: AtomicU64,
    /// Requests handled on a real-time (`SCHED_FIFO`/`SCHED_RR`) thread: must stay 0.
    pub realtime: AtomicU64,
    /// Connections closed at once because the surface was at its cap.
    pub shed: AtomicU64,
    /// Connections open now.
    pub open: AtomicU64,
}

static STATS: HttpStats = HttpStats {
    requests: AtomicU64::new(0),
    realtime: AtomicU64::new(0),
    shed: AtomicU64::new(0),
    open: AtomicU64::new(0),
};

/// The process's HTTP counters.
pub fn stats() -> &'static HttpStats {
    &STATS
}

impl HttpStats {
    /// The counters as JSON.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "http_requests": self.requests.load(Ordering::Relaxed),
            "http_requests_on_realtime_threads": self.realtime.load(Ordering::Relaxed),
            "http_connections_shed": self.shed.load(Ordering::Relaxed),
            "http_connections_open": self.open.load(Ordering::Relaxed),
        })
    }
}

/// Is the calling thread scheduled real-time (`SCHED_FIFO` or `SCHED_RR`)?
pub fn on_realtime_thread() -> bool {
    // SAFETY: sched_getscheduler(0) only reads the calling thread's policy.
    let p = unsafe { libc::sched_getscheduler(0) };
    p == libc::SCHED_FIFO || p == libc::SCHED_RR
}

/// Put the calling thread on ordinary scheduling (`SCHED_OTHER`), whatever it inherited.
pub fn make_current_thread_ordinary() -> Result<(), String> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: sched_setscheduler reads the param struct we pass for the calling thread (0).
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_OTHER, &param) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error().to_string())
    }
}

static RUNTIME: OnceLock<Result<tokio::runtime::Runtime, String>> = OnceLock::new();

/// The station runtime (built on first use, one per process, never dropped): ordinary-priority
/// threads named `antisurge-station`.
pub fn handle() -> Result<tokio::runtime::Handle, String> {
    RUNTIME
        .get_or_init(|| {
            tokio::runtime::Builder::new_multi_thread()
                .worker_threads(STATION_WORKER_THREADS)
                .max_blocking_threads(STATION_BLOCKING_THREADS)
                .thread_name("antisurge-station")
                .thread_stack_size(crate::runtime::rt_loop::WORKER_THREAD_STACK_BYTES)
                .on_thread_start(|| {
                    if let Err(e) = make_current_thread_ordinary() {
                        tracing::error!(target: "status", "station thread: cannot leave real-time scheduling: {e}");
                    }
                })
                .enable_all()
                .build()
                .map_err(|e| format!("cannot start the operator station's runtime: {e}"))
        })
        .as_ref()
        .map(|rt| rt.handle().clone())
        .map_err(Clone::clone)
}

/// Count the request and whether its handling thread is real-time, and bound its time.
async fn account(req: Request, next: axum::middleware::Next, limit: Duration) -> Response {
    STATS.requests.fetch_add(1, Ordering::Relaxed);
    if on_realtime_thread() {
        STATS.realtime.fetch_add(1, Ordering::Relaxed);
    }
    match tokio::time::timeout(limit, next.run(req)).await {
        Ok(r) => r,
        Err(_) => (
            StatusCode::SERVICE_UNAVAILABLE,
            "the request took too long and was abandoned\n",
        )
            .into_response(),
    }
}

/// The router with the station's accounting, handler time-out and body limit.
pub fn bounded(router: Router, limits: HttpLimits) -> Router {
    let t = limits.handler_timeout;
    router
        .layer(axum::extract::DefaultBodyLimit::max(limits.max_body_bytes))
        .layer(axum::middleware::from_fn(move |req, next| {
            account(req, next, t)
        }))
}

/// A stream that notes when it last moved a byte (for the idle time-out).
struct Watched<S> {
    inner: S,
    last: Arc<AtomicU64>,
    t0: Instant,
}

impl<S> Watched<S> {
    fn touch(&self) {
        self.last
            .store(self.t0.elapsed().as_millis() as u64, Ordering::Relaxed);
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Watched<S> {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let r = std::pin::Pin::new(&mut self.inner).poll_read(cx, buf);
        if buf.filled().len() > before {
            self.touch();
        }
        r
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Watched<S> {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        let r = std::pin::Pin::new(&mut self.inner).poll_write(cx, buf);
        if matches!(r, std::task::Poll::Ready(Ok(n)) if n > 0) {
            self.touch();
        }
        r
    }
    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// The peer of a connection, as handlers see it (`Extension<Peer>`).
#[derive(Debug, Clone, Copy)]
pub struct Peer {
    /// The client's address.
    pub addr: SocketAddr,
    /// Over TLS?
    pub tls: bool,
    /// The local address it connected to.
    pub local: SocketAddr,
}

/// Serve one connection with hyper (HTTP/1.1, keep-alive) until it ends, idles out or
/// `shutdown`.
async fn serve_connection<S>(
    io: S,
    router: Router,
    peer: Peer,
    limits: HttpLimits,
    mut shutdown: tokio::sync::watch::Receiver<bool>,
) where
    S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let t0 = Instant::now();
    let last = Arc::new(AtomicU64::new(0));
    let io = Watched {
        inner: io,
        last: Arc::clone(&last),
        t0,
    };
    let router = router.layer(axum::Extension(peer));
    let service = hyper_util::service::TowerToHyperService::new(router);
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .keep_alive(true)
        .header_read_timeout(limits.head_timeout)
        .max_buf_size(limits.max_buf_bytes)
        .max_headers(64);
    let conn = builder.serve_connection(TokioIo::new(io), service);
    tokio::pin!(conn);
    let mut tick = tokio::time::interval(Duration::from_millis(500));
    let mut closing = false;
    loop {
        tokio::select! {
            r = conn.as_mut() => {
                if let Err(e) = r {
                    tracing::debug!(target: "status", "HTTP connection from {}: {e}", peer.addr);
                }
                break;
            }
            _ = tick.tick(), if !closing => {
                let idle_ms = (t0.elapsed().as_millis() as u64).saturating_sub(last.load(Ordering::Relaxed));
                if idle_ms >= limits.idle_timeout.as_millis() as u64 {
                    conn.as_mut().graceful_shutdown();
                    closing = true;
                }
            }
            _ = shutdown.changed(), if !closing => {
                conn.as_mut().graceful_shutdown();
                closing = true;
            }
        }
    }
}

/// Serve `router` on `listener` (over TLS when `tls` is given) within `limits` until
/// `shutdown`. Must run on the station runtime.
pub async fn serve_http(
    listener: tokio::net::TcpListener,
    router: Router,
    tls: Option<tokio_rustls::TlsAcceptor>,
    limits: HttpLimits,
    mut shutdown: tokio::sync::watch::Receiver<bool>,
) {
    let router = bounded(router, limits);
    let slots = Arc::new(tokio::sync::Semaphore::new(limits.max_connections));
    let local = listener
        .local_addr()
        .unwrap_or_else(|_| SocketAddr::from(([0, 0, 0, 0], 0)));
    loop {
        let (mut sock, addr) = tokio::select! {
            r = listener.accept() => match r {
                Ok(s) => s,
                Err(e) => {
                    // out of descriptors, most likely: back off, carry on
                    tracing::debug!(target: "status", "HTTP accept on {local}: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            _ = shutdown.changed() => break,
        };
        let Ok(permit) = Arc::clone(&slots).try_acquire_owned() else {
            STATS.shed.fetch_add(1, Ordering::Relaxed);
            drop(sock);
            continue;
        };
        let _ = sock.set_nodelay(true);
        let (router, tls, shutdown) = (router.clone(), tls.clone(), shutdown.clone());
        tokio::spawn(async move {
            let _permit = permit;
            STATS.open.fetch_add(1, Ordering::Relaxed);
            let peer = Peer {
                addr,
                tls: tls.is_some(),
                local,
            };
            match tls {
                None => serve_connection(sock, router, peer, limits, shutdown).await,
                Some(acceptor) => {
                    // a TLS connection opens with a handshake record (0x16); plain HTTP gets
                    // a 400 that says to use https:// and nothing else
                    let mut first = [0u8; 1];
                    let opened =
                        tokio::time::timeout(limits.head_timeout, sock.peek(&mut first)).await;
                    if matches!(opened, Ok(Ok(1))) && first[0] != 0x16 {
                        let body = "this HMI is served over TLS only: open it with https://\n";
                        let resp = format!(
                            "HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
                            body.len()
                        );
                        let _ = sock.write_all(resp.as_bytes()).await;
                        let _ = sock.shutdown().await;
                    } else if matches!(opened, Ok(Ok(1))) {
                        match tokio::time::timeout(limits.head_timeout, acceptor.accept(sock)).await
                        {
                            Ok(Ok(stream)) => {
                                serve_connection(stream, router, peer, limits, shutdown).await
                            }
                            Ok(Err(e)) => {
                                tracing::debug!(target: "status", "TLS handshake with {addr}: {e}")
                            }
                            Err(_) => {
                                tracing::debug!(target: "status", "TLS handshake with {addr}: timed out")
                            }
                        }
                    }
                }
            }
            STATS.open.fetch_sub(1, Ordering::Relaxed);
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn station_threads_are_ordinary_even_when_started_from_a_realtime_thread() {
        // a thread that asks for SCHED_FIFO (granted to root / CAP_SYS_NICE; else the check
        // below holds trivially) starts the runtime: its workers must still be ordinary
        let h = std::thread::spawn(|| {
            let _ = crate::runtime::rt_loop::set_current_thread_fifo(10);
            let h = handle().expect("runtime");
            h.block_on(async {
                tokio::spawn(async { on_realtime_thread() })
                    .await
                    .expect("join")
            })
        });
        assert!(
            !h.join().expect("thread"),
            "a station worker runs real-time"
        );
    }
}
