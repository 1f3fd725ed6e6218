//! A read-only Modbus TCP server that survives abuse: the server of the DCS block
//! ([`crate::live::dcs`]).
//!
//! A DCS has a handful of stations polling a few times a second. Everything else that reaches
//! the port — scanners, a misconfigured client opening a connection per poll, a flood of idle
//! connections — must not take the block down. So, unlike the plant simulator's server
//! ([`super::server`]):
//!
//! - **connection cap** ([`ServerLimits::max_connections`]): at the cap a newcomer takes the
//!   place of the oldest connection that never sent a request, else of the connection idle
//!   the longest if it has been idle [`EVICT_IDLE_MIN`] or more; otherwise the newcomer is
//!   closed at once. A DCS station that polls keeps its place through any flood.
//! - **idle time-out** ([`ServerLimits::idle_timeout`]): no complete request for that long
//!   (also: a frame started and not finished, an answer the client does not read) closes
//!   the connection.
//! - **request budget** ([`ServerLimits::max_requests_per_s`]): a token bucket per
//!   connection (burst: one second's worth); a faster client is slowed down by not reading
//!   its socket, it is not served sooner.
//! - **descriptor exhaustion** (`EMFILE`, `ENFILE`, `ENOBUFS`, `ENOMEM` from `accept`): the
//!   accept loop backs off (10 ms doubling to 1 s), frees the descriptor of a connection that
//!   never sent a request if there is one, and keeps accepting. It never stops by itself.
//! - counters ([`ServerCounters`], in the metrics endpoint) and a report to the owner when
//!   connections are shed ([`ShedReport`], at most one per [`SHED_REPORT_EVERY`]).
//!
//! Only reads are served (functions 1–4); every write is answered with exception 1 (illegal
//! function). Frames are checked by [`super::request_guard::check_request_adu`] first; a bad
//! frame closes the connection.

use std::collections::HashMap;
use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;
use tokio::task::JoinSet;

use super::register::RegisterTable;
use super::request_guard::{check_request_adu, MAX_ADU_BYTES};
use super::server::{lock_image, SharedImage, TcpServerHandle};

/// At the cap, a connection that has sent requests is only displaced after this long idle.
pub const EVICT_IDLE_MIN: Duration = Duration::from_secs(1);

/// Shed reports are made at most this often (the counters carry the rest).
pub const SHED_REPORT_EVERY: Duration = Duration::from_secs(10);

/// First and longest pause of the accept loop after a descriptor-exhaustion error.
pub const ACCEPT_BACKOFF: (Duration, Duration) =
    (Duration::from_millis(10), Duration::from_secs(1));

/// The server's limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServerLimits {
    /// Most connections at once (≥ 1).
    pub max_connections: usize,
    /// Close a connection without a complete request for this long.
    pub idle_timeout: Duration,
    /// Requests per second per connection (burst: as many at once).
    pub max_requests_per_s: f64,
}

/// What the server has done, for the metrics endpoint (monotonic counters but `open`).
#[derive(Debug, Default)]
pub struct ServerCounters {
    /// Set while a server runs with these counters.
    pub serving: AtomicBool,
    /// Connections accepted.
    pub accepted: AtomicU64,
    /// Connections open now.
    pub open: AtomicU64,
    /// Connections closed to make room at the cap, or refused at it.
    pub shed: AtomicU64,
    /// Connections closed by the idle time-out.
    pub idle_closed: AtomicU64,
    /// Requests held back by the per-connection budget.
    pub throttled: AtomicU64,
    /// `accept` failures for want of descriptors or memory (each followed by a back-off).
    pub accept_exhausted: AtomicU64,
    /// Requests answered (including exception answers).
    pub requests: AtomicU64,
    /// Connections closed on a malformed frame.
    pub malformed: AtomicU64,
}

/// A copy of [`ServerCounters`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CountersSnapshot {
    /// See [`ServerCounters::accepted`].
    pub accepted: u64,
    /// See [`ServerCounters::open`].
    pub open: u64,
    /// See [`ServerCounters::shed`].
    pub shed: u64,
    /// See [`ServerCounters::idle_closed`].
    pub idle_closed: u64,
    /// See [`ServerCounters::throttled`].
    pub throttled: u64,
    /// See [`ServerCounters::accept_exhausted`].
    pub accept_exhausted: u64,
    /// See [`ServerCounters::requests`].
    pub requests: u64,
    /// See [`ServerCounters::malformed`].
    pub malformed: u64,
}

impl ServerCounters {
    /// Read every counter.
    pub fn snapshot(&self) -> CountersSnapshot {
        let r = |a: &AtomicU64| a.load(Ordering::Relaxed);
        CountersSnapshot {
            accepted: r(&self.accepted),
            open: r(&self.open),
            shed: r(&self.shed),
            idle_closed: r(&self.idle_closed),
            throttled: r(&self.throttled),
            accept_exhausted: r(&self.accept_exhausted),
            requests: r(&self.requests),
            malformed: r(&self.malformed),
        }
    }
}

/// Why connections were shed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShedCause {
    /// The connection cap was reached.
    ConnectionCap,
    /// `accept` failed for want of descriptors (`EMFILE` and the like).
    DescriptorsExhausted,
}

/// Handed to the owner when the server sheds connections (rate-limited).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShedReport {
    /// The server's address.
    pub local_addr: SocketAddr,
    /// Why.
    pub cause: ShedCause,
    /// The operating-system error, for [`ShedCause::DescriptorsExhausted`].
    pub error: Option<String>,
    /// The counters when reported.
    pub counters: CountersSnapshot,
}

/// Receives [`ShedReport`]s (from the server's tasks; must not block).
pub type ShedSink = Arc<dyn Fn(ShedReport) + Send + Sync>;

/// One connection as the accept loop sees it.
struct ConnState {
    opened_ms: u64,
    /// Last complete request, ms since the server started; `u64::MAX`: none yet.
    last_request_ms: AtomicU64,
    kill: Notify,
}

struct Shared {
    image: SharedImage,
    limits: ServerLimits,
    counters: Arc<ServerCounters>,
    conns: Mutex<HashMap<u64, Arc<ConnState>>>,
    epoch: Instant,
}

impl Shared {
    fn now_ms(&self) -> u64 {
        self.epoch.elapsed().as_millis() as u64
    }

    fn conns(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Arc<ConnState>>> {
        self.conns
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Close the connection the policy gives up first; `false`: none may go.
    /// `served_too`: a connection that has sent requests may go if idle long enough.
    fn evict_one(&self, served_too: bool) -> bool {
        let now = self.now_ms();
        let mut conns = self.conns();
        let never = conns
            .iter()
            .filter(|(_, c)| c.last_request_ms.load(Ordering::Relaxed) == u64::MAX)
            .min_by_key(|(_, c)| c.opened_ms)
            .map(|(&id, _)| id);
        let victim = never.or_else(|| {
            if !served_too {
                return None;
            }
            conns
                .iter()
                .map(|(&id, c)| (id, c.last_request_ms.load(Ordering::Relaxed)))
                .filter(|&(_, t)| now.saturating_sub(t) >= EVICT_IDLE_MIN.as_millis() as u64)
                .min_by_key(|&(_, t)| t)
                .map(|(id, _)| id)
        });
        match victim.and_then(|id| conns.remove(&id)) {
            Some(c) => {
                c.kill.notify_one();
                true
            }
            None => false,
        }
    }
}

/// Serve `image` read-only on `listener` within `limits`; `on_shed` hears about shed
/// connections. Dropping or shutting down the handle closes the listener and every
/// connection.
pub fn spawn_bounded_tcp_server(
    listener: TcpListener,
    image: SharedImage,
    limits: ServerLimits,
    counters: Arc<ServerCounters>,
    on_shed: ShedSink,
) -> io::Result<TcpServerHandle> {
    let local_addr = listener.local_addr()?;
    let limits = ServerLimits {
        max_connections: limits.max_connections.max(1),
        ..limits
    };
    let shared = Arc::new(Shared {
        image,
        limits,
        counters,
        conns: Mutex::new(HashMap::new()),
        epoch: Instant::now(),
    });
    let task = tokio::spawn(accept_loop(listener, local_addr, shared, on_shed));
    Ok(TcpServerHandle::from_task(local_addr, task))
}

fn is_exhaustion(e: &io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(libc::EMFILE | libc::ENFILE | libc::ENOBUFS | libc::ENOMEM)
    )
}

async fn accept_loop(
    listener: TcpListener,
    local_addr: SocketAddr,
    shared: Arc<Shared>,
    on_shed: ShedSink,
) {
    let counters = Arc::clone(&shared.counters);
    counters.serving.store(true, Ordering::Relaxed);
    // aborting this task drops the set, which aborts every connection task
    let mut tasks = JoinSet::new();
    let mut next_id = 0u64;
    let mut backoff = ACCEPT_BACKOFF.0;
    let mut last_report: Option<Instant> = None;
    let mut report = |cause: ShedCause, error: Option<String>| {
        if last_report.is_some_and(|t| t.elapsed() < SHED_REPORT_EVERY) {
            return;
        }
        last_report = Some(Instant::now());
        on_shed(ShedReport {
            local_addr,
            cause,
            error,
            counters: counters.snapshot(),
        });
    };
    loop {
        while tasks.try_join_next().is_some() {}
        match listener.accept().await {
            Ok((stream, peer)) => {
                backoff = ACCEPT_BACKOFF.0;
                counters.accepted.fetch_add(1, Ordering::Relaxed);
                let full = shared.conns().len() >= shared.limits.max_connections;
                if full && !shared.evict_one(true) {
                    // every place is held by a client that polls: the newcomer goes
                    counters.shed.fetch_add(1, Ordering::Relaxed);
                    drop(stream);
                    report(ShedCause::ConnectionCap, None);
                    continue;
                }
                if full {
                    counters.shed.fetch_add(1, Ordering::Relaxed);
                    report(ShedCause::ConnectionCap, None);
                }
                next_id += 1;
                let state = Arc::new(ConnState {
                    opened_ms: shared.now_ms(),
                    last_request_ms: AtomicU64::new(u64::MAX),
                    kill: Notify::new(),
                });
                shared.conns().insert(next_id, Arc::clone(&state));
                counters.open.fetch_add(1, Ordering::Relaxed);
                let shared = Arc::clone(&shared);
                let id = next_id;
                tasks.spawn(async move {
                    serve_connection(stream, peer, &shared, &state).await;
                    shared.conns().remove(&id);
                    shared.counters.open.fetch_sub(1, Ordering::Relaxed);
                });
            }
            Err(e) if is_exhaustion(&e) => {
                counters.accept_exhausted.fetch_add(1, Ordering::Relaxed);
                if shared.evict_one(false) {
                    counters.shed.fetch_add(1, Ordering::Relaxed);
                }
                report(ShedCause::DescriptorsExhausted, Some(e.to_string()));
                tracing::debug!(target: "modbus", error = %e, "accept: out of descriptors, backing off {backoff:?}");
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(ACCEPT_BACKOFF.1);
            }
            Err(e) => {
                // a connection reset before it was accepted and the like: not the server's
                tracing::debug!(target: "modbus", error = %e, "accept failed");
                tokio::time::sleep(ACCEPT_BACKOFF.0).await;
            }
        }
    }
}

async fn serve_connection(
    mut stream: TcpStream,
    peer: SocketAddr,
    shared: &Shared,
    state: &ConnState,
) {
    let _ = stream.set_nodelay(true);
    let limits = shared.limits;
    let rate = limits.max_requests_per_s.max(1e-3);
    let burst = rate.max(1.0);
    let mut tokens = burst;
    let mut refilled = Instant::now();
    let mut adu = [0u8; MAX_ADU_BYTES];
    let mut out = Vec::with_capacity(MAX_ADU_BYTES);
    let timed_out = || {
        shared.counters.idle_closed.fetch_add(1, Ordering::Relaxed);
        tracing::debug!(target: "modbus", %peer, "idle connection closed");
    };
    loop {
        // header: the idle time-out runs from the last answer
        let header = tokio::select! {
            () = state.kill.notified() => return,
            r = tokio::time::timeout(limits.idle_timeout, stream.read_exact(&mut adu[..7])) => r,
        };
        match header {
            Err(_) => return timed_out(),
            Ok(Err(_)) => return,
            Ok(Ok(_)) => {}
        }
        let length = usize::from(u16::from_be_bytes([adu[4], adu[5]]));
        if !(2..=MAX_ADU_BYTES - 6).contains(&length) || adu[2] != 0 || adu[3] != 0 {
            shared.counters.malformed.fetch_add(1, Ordering::Relaxed);
            return;
        }
        let end = 6 + length;
        let body = tokio::select! {
            () = state.kill.notified() => return,
            r = tokio::time::timeout(limits.idle_timeout, stream.read_exact(&mut adu[7..end])) => r,
        };
        match body {
            Err(_) => return timed_out(),
            Ok(Err(_)) => return,
            Ok(Ok(_)) => {}
        }
        if check_request_adu(&adu[..end]).is_err() {
            shared.counters.malformed.fetch_add(1, Ordering::Relaxed);
            return;
        }
        // the budget: wait for a token (the socket is not read meanwhile)
        let now = Instant::now();
        tokens = (tokens + now.duration_since(refilled).as_secs_f64() * rate).min(burst);
        refilled = now;
        if tokens < 1.0 {
            shared.counters.throttled.fetch_add(1, Ordering::Relaxed);
            let wait = Duration::from_secs_f64((1.0 - tokens) / rate);
            tokio::select! {
                () = state.kill.notified() => return,
                () = tokio::time::sleep(wait) => {}
            }
            let now = Instant::now();
            tokens = (tokens + now.duration_since(refilled).as_secs_f64() * rate).min(burst);
            refilled = now;
        }
        tokens -= 1.0;
        state
            .last_request_ms
            .store(shared.now_ms(), Ordering::Relaxed);
        answer(&shared.image, &adu[..end], &mut out);
        shared.counters.requests.fetch_add(1, Ordering::Relaxed);
        let sent = tokio::select! {
            () = state.kill.notified() => return,
            r = tokio::time::timeout(limits.idle_timeout, stream.write_all(&out)) => r,
        };
        match sent {
            Err(_) => return timed_out(),
            Ok(Err(_)) => return,
            Ok(Ok(())) => {}
        }
    }
}

/// The answer ADU to a checked request ADU (MBAP header + PDU), into `out`.
fn answer(image: &SharedImage, adu: &[u8], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&adu[..4]); // transaction and protocol id
    out.extend_from_slice(&[0, 0]); // length, set below
    out.push(adu[6]);
    let (unit, pdu) = (adu[6], &adu[7..]);
    let fc = pdu[0];
    if let Err(code) = read_pdu(image, unit, pdu, out) {
        out.truncate(7);
        out.push(fc | 0x80);
        out.push(code);
    }
    let length = (out.len() - 6) as u16;
    out[4..6].copy_from_slice(&length.to_be_bytes());
}

/// Exception codes.
const ILLEGAL_FUNCTION: u8 = 0x01;
const ILLEGAL_DATA_ADDRESS: u8 = 0x02;
const ILLEGAL_DATA_VALUE: u8 = 0x03;
const GATEWAY_TARGET: u8 = 0x0B;

fn read_pdu(image: &SharedImage, unit: u8, pdu: &[u8], out: &mut Vec<u8>) -> Result<(), u8> {
    let fc = pdu[0];
    let table = match fc {
        1 => RegisterTable::Coil,
        2 => RegisterTable::DiscreteInput,
        3 => RegisterTable::Holding,
        4 => RegisterTable::Input,
        _ => return Err(ILLEGAL_FUNCTION), // every write: the block is read-only
    };
    if pdu.len() != 5 {
        return Err(ILLEGAL_DATA_VALUE);
    }
    let address = u16::from_be_bytes([pdu[1], pdu[2]]);
    let count = u16::from_be_bytes([pdu[3], pdu[4]]);
    let bits = fc <= 2;
    let max = if bits { 2000 } else { 125 };
    if count == 0 || count > max {
        return Err(ILLEGAL_DATA_VALUE);
    }
    let mut words = [0u16; 2000];
    let words = &mut words[..usize::from(count)];
    {
        let image = lock_image(image);
        if !image.has_unit(unit) {
            return Err(GATEWAY_TARGET);
        }
        image
            .read_words(unit, table, address, words)
            .map_err(|_| ILLEGAL_DATA_ADDRESS)?;
    }
    out.push(fc);
    if bits {
        let n = words.len().div_ceil(8);
        out.push(n as u8);
        for chunk in words.chunks(8) {
            let byte = chunk
                .iter()
                .enumerate()
                .fold(0u8, |b, (i, &w)| b | (u8::from(w != 0) << i));
            out.push(byte);
        }
    } else {
        out.push((2 * words.len()) as u8);
        for w in words.iter() {
            out.extend_from_slice(&w.to_be_bytes());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::modbus::server::RegisterImage;

    fn image() -> SharedImage {
        let mut img = RegisterImage::new();
        img.map(1, RegisterTable::Input, 0, 4);
        img.map(1, RegisterTable::DiscreteInput, 0, 10);
        img.write_words(1, RegisterTable::Input, 0, &[1, 2, 0xABCD, 4])
            .expect("mapped");
        img.write_words(
            1,
            RegisterTable::DiscreteInput,
            0,
            &[1, 0, 0, 0, 0, 0, 0, 0, 1, 1],
        )
        .expect("mapped");
        img.into_shared()
    }

    fn ask(img: &SharedImage, pdu: &[u8]) -> Vec<u8> {
        let mut adu = vec![0x12, 0x34, 0, 0, 0, (pdu.len() + 1) as u8, 1];
        adu.extend_from_slice(pdu);
        let mut out = Vec::new();
        answer(img, &adu, &mut out);
        assert_eq!(
            &out[..4],
            &[0x12, 0x34, 0, 0],
            "transaction and protocol echoed"
        );
        assert_eq!(
            usize::from(u16::from_be_bytes([out[4], out[5]])),
            out.len() - 6
        );
        out[7..].to_vec()
    }

    #[test]
    fn reads_are_answered_and_writes_refused() {
        let img = image();
        assert_eq!(
            ask(&img, &[4, 0, 1, 0, 2]),
            [4, 4, 0, 2, 0xAB, 0xCD],
            "input registers 1-2"
        );
        assert_eq!(ask(&img, &[2, 0, 0, 0, 10]), [2, 2, 0x01, 0x03]);
        assert_eq!(ask(&img, &[4, 0, 3, 0, 2]), [0x84, ILLEGAL_DATA_ADDRESS]);
        assert_eq!(ask(&img, &[4, 0, 0, 0, 0]), [0x84, ILLEGAL_DATA_VALUE]);
        assert_eq!(ask(&img, &[3, 0, 0, 0, 1]), [0x83, ILLEGAL_DATA_ADDRESS]);
        assert_eq!(ask(&img, &[6, 0, 0, 0, 1]), [0x86, ILLEGAL_FUNCTION]);
        assert_eq!(
            ask(&img, &[0x10, 0, 0, 0, 1, 2, 0, 5]),
            [0x90, ILLEGAL_FUNCTION]
        );
        let mut adu = vec![0, 1, 0, 0, 0, 6, 9, 4, 0, 0, 0, 1];
        let mut out = Vec::new();
        answer(&img, &adu, &mut out);
        assert_eq!(&out[7..], [0x84, GATEWAY_TARGET], "unknown unit");
        adu[6] = 1;
        answer(&img, &adu, &mut out);
        assert_eq!(&out[7..], [4, 2, 0, 1]);
    }

    #[test]
    fn eviction_prefers_connections_that_never_asked() {
        let shared = Shared {
            image: image(),
            limits: ServerLimits {
                max_connections: 3,
                idle_timeout: Duration::from_secs(30),
                max_requests_per_s: 20.0,
            },
            counters: Arc::default(),
            conns: Mutex::new(HashMap::new()),
            epoch: Instant::now(),
        };
        let state = |opened_ms: u64, last: u64| {
            Arc::new(ConnState {
                opened_ms,
                last_request_ms: AtomicU64::new(last),
                kill: Notify::new(),
            })
        };
        let now = shared.now_ms();
        shared.conns().insert(1, state(0, now)); // polling now
        shared.conns().insert(2, state(5, u64::MAX)); // never asked, newer
        shared.conns().insert(3, state(1, u64::MAX)); // never asked, older
        assert!(shared.evict_one(false));
        assert!(
            !shared.conns().contains_key(&3),
            "the oldest silent one goes first"
        );
        assert!(shared.evict_one(true));
        assert!(!shared.conns().contains_key(&2));
        assert!(
            !shared.evict_one(false) && !shared.evict_one(true),
            "a client that polls is never displaced while it polls"
        );
        assert!(shared.conns().contains_key(&1));
    }
}
