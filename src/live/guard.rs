//! What stands between an HTTP client and an operator action (issue 24):
//!
//! - [`AuthGuard`]: wrong-token attempts counted per source address. After
//!   [`MAX_FAILURES`] in one burst the source gets 429 for every operator action, the right
//!   token included, until it has been quiet for [`BURST_QUIET`]. Each burst is reported
//!   **once**, when it ends (or every [`BURST_REPORT_EVERY`] while it goes on): one journal
//!   line and one event with the source and the count, never a line per attempt.
//! - [`host_allowed`] and [`origin_allowed`]: the `Host` header must name this machine (an
//!   address literal, `localhost`, or the host name) on the port the surface listens on, and
//!   an `Origin` header, when a browser sends one, must be the page's own origin. A page of
//!   another site (DNS rebinding, cross-site requests) is refused with 403.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use crate::events::{Event, EventSender};

/// Wrong tokens from one source, within one burst, before it gets 429. An operator who
/// mistypes does so a few times; a guesser needs millions.
pub const MAX_FAILURES: u64 = 10;

/// A burst ends when its source has made no attempt for this long (a person retyping a token
/// takes longer than this between attempts only when giving up).
pub const BURST_QUIET: Duration = Duration::from_secs(5);

/// A burst that goes on is reported at least this often (a minute: the journal and the event
/// log get one line a minute per source, not one per attempt).
pub const BURST_REPORT_EVERY: Duration = Duration::from_secs(60);

/// Sources tracked at once (a flood from many addresses is folded into one "other" entry).
pub const MAX_SOURCES: usize = 1024;

#[derive(Debug, Clone)]
struct Burst {
    first: Instant,
    last: Instant,
    reported_at: Instant,
    /// Wrong tokens (each got 401).
    failures: u64,
    /// Attempts refused with 429, whatever their token.
    refused: u64,
}

/// One reported burst.
#[derive(Debug, Clone, PartialEq)]
pub struct BurstReport {
    /// The source address (`None`: the overflow entry of [`MAX_SOURCES`]).
    pub source: Option<IpAddr>,
    /// Wrong-token attempts in the report's span (401).
    pub failures: u64,
    /// Attempts answered 429 in the span.
    pub refused: u64,
    /// The span, s.
    pub span_s: f64,
    /// The burst goes on (a periodic report).
    pub ongoing: bool,
}

impl BurstReport {
    /// The one line for the journal and the event log.
    pub fn text(&self) -> String {
        let src = self
            .source
            .map_or_else(|| "other sources".to_string(), |a| a.to_string());
        format!(
            "{} operator action(s) with a wrong or no token from {src} over {:.1} s ({} answered 401, {} refused with 429 after {MAX_FAILURES} failures){}",
            self.failures + self.refused,
            self.span_s,
            self.failures,
            self.refused,
            if self.ongoing { "; still going on" } else { "" }
        )
    }
}

/// Wrong-token bookkeeping of the HTTP surfaces.
#[derive(Debug, Default)]
pub struct AuthGuard {
    bursts: Mutex<HashMap<Option<IpAddr>, Burst>>,
}

impl AuthGuard {
    fn key(map: &HashMap<Option<IpAddr>, Burst>, ip: IpAddr) -> Option<IpAddr> {
        if map.contains_key(&Some(ip)) || map.len() < MAX_SOURCES {
            Some(ip)
        } else {
            None
        }
    }

    /// May `ip` attempt an operator action now? `false`: answer 429 (the attempt is counted).
    pub fn admit(&self, ip: IpAddr, now: Instant) -> bool {
        let Ok(mut map) = self.bursts.lock() else {
            return false;
        };
        let k = Self::key(&map, ip);
        match map.get_mut(&k) {
            Some(b) if b.failures >= MAX_FAILURES => {
                b.refused += 1;
                b.last = now;
                false
            }
            _ => true,
        }
    }

    /// `ip` gave a wrong or no token.
    pub fn failed(&self, ip: IpAddr, now: Instant) {
        let Ok(mut map) = self.bursts.lock() else {
            return;
        };
        let k = Self::key(&map, ip);
        let b = map.entry(k).or_insert(Burst {
            first: now,
            last: now,
            reported_at: now,
            failures: 0,
            refused: 0,
        });
        b.failures += 1;
        b.last = now;
    }

    /// The bursts to report at `now`: ended ones (quiet for [`BURST_QUIET`], then forgotten)
    /// and the running ones not reported for [`BURST_REPORT_EVERY`] (their counts restart).
    pub fn due(&self, now: Instant) -> Vec<BurstReport> {
        let Ok(mut map) = self.bursts.lock() else {
            return Vec::new();
        };
        let mut out = Vec::new();
        map.retain(|src, b| {
            let ended = now.saturating_duration_since(b.last) >= BURST_QUIET;
            let periodic = now.saturating_duration_since(b.reported_at) >= BURST_REPORT_EVERY;
            if ended || periodic {
                out.push(BurstReport {
                    source: *src,
                    failures: b.failures,
                    refused: b.refused,
                    span_s: b.last.saturating_duration_since(b.first).as_secs_f64(),
                    ongoing: !ended,
                });
            }
            if ended {
                return false;
            }
            if periodic {
                // keep the lock-out (failures stay at the cap), restart the counts shown
                b.first = now;
                b.reported_at = now;
                b.refused = 0;
                b.failures = b.failures.min(MAX_FAILURES);
            }
            true
        });
        out
    }

    /// Report what is due: one warning line and one event per burst.
    pub fn report_due(&self, now: Instant, events: &EventSender) {
        for r in self.due(now) {
            let text = r.text();
            tracing::warn!(target: "operator", source = %r.source.map_or_else(|| "other".into(), |a| a.to_string()),
                attempts = r.failures + r.refused, "{text}");
            let _ = events.send(Event::Note { text });
        }
    }
}

/// The machine's host name (`gethostname`), empty if unknown.
pub fn host_name() -> String {
    let mut buf = [0u8; 256];
    // SAFETY: gethostname writes at most buf.len() bytes into buf.
    let r = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) };
    if r != 0 {
        return String::new();
    }
    let n = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    String::from_utf8_lossy(&buf[..n]).into_owned()
}

/// Split `host[:port]` (`[v6]:port` too); the port is `default_port` when absent.
fn split_host(text: &str, default_port: u16) -> Option<(String, u16)> {
    let text = text.trim();
    if let Some(rest) = text.strip_prefix('[') {
        let (h, after) = rest.split_once(']')?;
        let port = match after.strip_prefix(':') {
            Some(p) => p.parse().ok()?,
            None if after.is_empty() => default_port,
            None => return None,
        };
        return Some((h.to_ascii_lowercase(), port));
    }
    match text.rsplit_once(':') {
        Some((h, p)) if !h.contains(':') => Some((h.to_ascii_lowercase(), p.parse().ok()?)),
        Some(_) => None,
        None => Some((text.to_ascii_lowercase(), default_port)),
    }
}

/// Does `host` (the `Host` header) name this machine? Address literals, `localhost` and the
/// machine's host name (`host_name`, alone or followed by its domain) pass; any other name is
/// a page of another site reaching the HMI (DNS rebinding). The port is not compared: an SSH
/// tunnel (`ssh -L 8080:127.0.0.1:9651`) shows the HMI on another port.
pub fn host_allowed(host: Option<&str>, tls: bool, host_name: &str) -> bool {
    let Some(host) = host else { return false };
    let default = if tls { 443 } else { 80 };
    let Some((name, _port)) = split_host(host, default) else {
        return false;
    };
    if name.parse::<IpAddr>().is_ok() || name == "localhost" || name.ends_with(".localhost") {
        return true;
    }
    let me = host_name.to_ascii_lowercase();
    !me.is_empty()
        && (name == me
            || name
                .strip_prefix(&me)
                .is_some_and(|rest| rest.starts_with('.')))
}

/// Is `origin` (the `Origin` header; absent for non-browser clients) the origin of the page
/// this `host` serves?
pub fn origin_allowed(origin: Option<&str>, host: Option<&str>, tls: bool) -> bool {
    let Some(origin) = origin else { return true };
    let Some(host) = host else { return false };
    let scheme = if tls { "https://" } else { "http://" };
    let Some(rest) = origin.trim().strip_prefix(scheme) else {
        return false;
    };
    let default = if tls { 443 } else { 80 };
    match (split_host(rest, default), split_host(host, default)) {
        (Some(a), Some(b)) => a == b,
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_thousand_wrong_tokens_make_one_report_and_429_after_the_limit() {
        let g = AuthGuard::default();
        let ip: IpAddr = "127.0.0.1".parse().expect("ip");
        let t0 = Instant::now();
        let mut codes = Vec::new();
        for k in 0..1000u64 {
            let now = t0 + Duration::from_millis(k);
            if g.admit(ip, now) {
                g.failed(ip, now);
                codes.push(401);
            } else {
                codes.push(429);
            }
            assert!(g.due(now).is_empty(), "reported while the burst goes on");
        }
        assert!(codes[..MAX_FAILURES as usize].iter().all(|&c| c == 401));
        assert!(codes[MAX_FAILURES as usize..].iter().all(|&c| c == 429));
        let end = t0 + Duration::from_millis(999) + BURST_QUIET;
        let r = g.due(end);
        assert_eq!(r.len(), 1, "{r:?}");
        assert_eq!(
            (r[0].failures, r[0].refused),
            (MAX_FAILURES, 1000 - MAX_FAILURES)
        );
        assert!(
            r[0].text().starts_with("1000 operator action(s)"),
            "{}",
            r[0].text()
        );
        assert!(r[0].text().contains("127.0.0.1"), "{}", r[0].text());
        assert!(g.due(end).is_empty(), "reported twice");
        assert!(g.admit(ip, end), "still locked out after the burst ended");
    }

    #[test]
    fn a_long_burst_is_reported_once_a_minute() {
        let g = AuthGuard::default();
        let ip: IpAddr = "10.0.0.9".parse().expect("ip");
        let t0 = Instant::now();
        let mut reports = 0;
        for s in 0..150u64 {
            let now = t0 + Duration::from_secs(s);
            if g.admit(ip, now) {
                g.failed(ip, now);
            }
            reports += g.due(now).len();
        }
        assert_eq!(reports, 2);
        assert!(!g.admit(ip, t0 + Duration::from_secs(150)));
    }

    #[test]
    fn host_and_origin() {
        let ok = |h: &str| host_allowed(Some(h), false, "skid4");
        assert!(ok("127.0.0.1:9651"));
        assert!(ok("localhost:9651"));
        assert!(ok("[::1]:9651"));
        assert!(ok("skid4:9651"));
        assert!(ok("SKID4.plant.example:9651"));
        assert!(!ok("evil.example:9651"), "rebinding name");
        assert!(!ok("skid4x:9651"));
        assert!(ok("localhost:8080"), "an SSH tunnel's port");
        assert!(ok("127.0.0.1"));
        assert!(!ok("x"));
        assert!(!host_allowed(None, false, "skid4"));
        assert!(origin_allowed(None, Some("127.0.0.1:9651"), false));
        assert!(origin_allowed(
            Some("http://127.0.0.1:9651"),
            Some("127.0.0.1:9651"),
            false
        ));
        assert!(!origin_allowed(
            Some("http://evil.example"),
            Some("127.0.0.1:9651"),
            false
        ));
        assert!(!origin_allowed(
            Some("http://127.0.0.1:9651"),
            Some("127.0.0.1:9651"),
            true
        ));
        assert!(!origin_allowed(Some("null"), Some("127.0.0.1:9651"), false));
    }
}
