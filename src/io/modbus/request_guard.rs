//! A guard in front of tokio-modbus's request decoder (Modbus TCP server side).
//!
//! tokio-modbus 0.17 panics (index out of bounds) on a Write Multiple Coils request whose byte
//! count is smaller than its quantity needs, e.g. the 13-byte ADU
//! `00 01 00 00 00 07 01 0f 00 00 00 10 00`, and computes `quantity * 2` in `u16` for 0x10 and
//! 0x17 (an overflow panic in debug builds). Every connection of the plant's server goes
//! through [`guard_connection`]: it reads whole MBAP frames from the socket, checks them with
//! [`check_request_adu`], forwards only sound ones to the decoder, and closes the connection
//! on the first bad one. Rejections are logged at most once per [`LOG_EVERY`].

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};
use tokio::net::TcpStream;

/// Rejected requests are logged at most this often (a count of the others follows).
pub const LOG_EVERY: Duration = Duration::from_secs(10);

/// Largest Modbus TCP ADU: 7-byte MBAP header + 253-byte PDU.
pub const MAX_ADU_BYTES: usize = 260;

/// Check one complete Modbus TCP request ADU (MBAP header + PDU). `Err` says why it would
/// not be safe to hand to the decoder.
pub fn check_request_adu(adu: &[u8]) -> Result<(), &'static str> {
    if adu.len() < 8 {
        return Err("shorter than an MBAP header and a function code");
    }
    if adu.len() > MAX_ADU_BYTES {
        return Err("longer than the largest Modbus TCP frame");
    }
    let length = usize::from(u16::from_be_bytes([adu[4], adu[5]]));
    if length != adu.len() - 6 {
        return Err("MBAP length does not match the frame");
    }
    check_request_pdu(&adu[7..])
}

/// Check a request PDU (function code first) for the multi-item writes the decoder trusts.
pub fn check_request_pdu(pdu: &[u8]) -> Result<(), &'static str> {
    let u16_at =
        |i: usize| -> Option<u16> { Some(u16::from_be_bytes([*pdu.get(i)?, *pdu.get(i + 1)?])) };
    match pdu.first() {
        None => Err("empty PDU"),
        Some(0x0F) => {
            let (Some(q), Some(&n)) = (u16_at(3), pdu.get(5)) else {
                return Err("write multiple coils: truncated header");
            };
            if !(1..=0x07B0).contains(&q) {
                return Err("write multiple coils: quantity outside 1–1968");
            }
            if usize::from(n) != usize::from(q).div_ceil(8) || pdu.len() != 6 + usize::from(n) {
                return Err("write multiple coils: byte count does not match the quantity");
            }
            Ok(())
        }
        Some(0x10) => {
            let (Some(q), Some(&n)) = (u16_at(3), pdu.get(5)) else {
                return Err("write multiple registers: truncated header");
            };
            if !(1..=123).contains(&q) {
                return Err("write multiple registers: quantity outside 1–123");
            }
            if usize::from(n) != 2 * usize::from(q) || pdu.len() != 6 + usize::from(n) {
                return Err("write multiple registers: byte count does not match the quantity");
            }
            Ok(())
        }
        Some(0x17) => {
            let (Some(q), Some(&n)) = (u16_at(7), pdu.get(9)) else {
                return Err("read/write multiple registers: truncated header");
            };
            if !(1..=121).contains(&q) {
                return Err("read/write multiple registers: write quantity outside 1–121");
            }
            if usize::from(n) != 2 * usize::from(q) || pdu.len() != 10 + usize::from(n) {
                return Err("read/write multiple registers: byte count does not match");
            }
            Ok(())
        }
        Some(_) => Ok(()),
    }
}

static LAST_LOG_S: AtomicU64 = AtomicU64::new(0);
static SUPPRESSED: AtomicU64 = AtomicU64::new(0);

fn log_rejection(peer: SocketAddr, why: &str) {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let last = LAST_LOG_S.load(Ordering::Relaxed);
    if now >= last + LOG_EVERY.as_secs()
        && LAST_LOG_S
            .compare_exchange(last, now, Ordering::Relaxed, Ordering::Relaxed)
            .is_ok()
    {
        let more = SUPPRESSED.swap(0, Ordering::Relaxed);
        tracing::warn!(target: "modbus", %peer, "malformed Modbus request refused and connection closed: {why} ({more} more since the last message)");
    } else {
        SUPPRESSED.fetch_add(1, Ordering::Relaxed);
    }
}

/// Put the guard between `stream` and the Modbus server: returns the stream the server
/// should serve; a task forwards checked requests one way and responses the other.
pub fn guard_connection(stream: TcpStream, peer: SocketAddr) -> DuplexStream {
    let (server_side, guard_side) = tokio::io::duplex(4 * MAX_ADU_BYTES);
    tokio::spawn(async move {
        let (mut tcp_r, mut tcp_w) = stream.into_split();
        let (mut dup_r, mut dup_w) = tokio::io::split(guard_side);
        let up = async move {
            let mut adu = [0u8; MAX_ADU_BYTES];
            loop {
                if tcp_r.read_exact(&mut adu[..7]).await.is_err() {
                    return;
                }
                let length = usize::from(u16::from_be_bytes([adu[4], adu[5]]));
                if !(2..=MAX_ADU_BYTES - 6).contains(&length) {
                    log_rejection(peer, "MBAP length outside 2–254");
                    return;
                }
                let end = 6 + length;
                if tcp_r.read_exact(&mut adu[7..end]).await.is_err() {
                    return;
                }
                if let Err(why) = check_request_adu(&adu[..end]) {
                    log_rejection(peer, why);
                    return;
                }
                if dup_w.write_all(&adu[..end]).await.is_err() {
                    return;
                }
            }
        };
        let down = tokio::io::copy(&mut dup_r, &mut tcp_w);
        tokio::select! {
            _ = up => {}
            _ = down => {}
        }
    });
    server_side
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_campaign_request_and_overflows_are_refused() {
        // issue 12, item 9: this ADU panicked tokio-modbus 0.17's decoder
        let bad = [
            0x00, 0x01, 0x00, 0x00, 0x00, 0x07, 0x01, 0x0f, 0x00, 0x00, 0x00, 0x10, 0x00,
        ];
        assert!(check_request_adu(&bad).is_err());
        // quantity * 2 overflows u16 in the decoder
        assert!(check_request_pdu(&[0x10, 0, 0, 0x80, 0x00, 0x00]).is_err());
        assert!(check_request_pdu(&[0x17, 0, 0, 0, 1, 0, 0, 0x80, 0x00, 0x00]).is_err());
        // sound requests pass
        assert!(check_request_pdu(&[0x0f, 0, 0, 0, 0x10, 2, 0xff, 0x00]).is_ok());
        assert!(check_request_pdu(&[0x10, 0, 10, 0, 1, 2, 0x12, 0x34]).is_ok());
        assert!(check_request_pdu(&[0x03, 0, 0, 0, 2]).is_ok());
        assert!(check_request_pdu(&[0x17, 0, 0, 0, 1, 0, 9, 0, 1, 2, 0, 5]).is_ok());
    }
}
