//! One open CAN_RAW socket, registered with tokio.
//!
//! Why not `socketcan::tokio::CanSocket`: its reads wait for *readable* only. When the
//! interface goes down the kernel sets the socket error (`ENETDOWN`) and signals `EPOLLERR`
//! without `EPOLLIN`, so a reader waiting for data on a quiet bus would never learn of it.
//! Here reads wait for readable **or error**, and the pending error is returned by the read.
//!
//! The socket is a CAN FD socket (`CAN_RAW_FD_FRAMES`) so that FD frames on an FD-capable
//! interface are seen and counted instead of silently dropped by the kernel; classic frames are
//! read and written as usual. The error filter is set to every error class, so bus-off and
//! controller state changes arrive as error frames.

use std::io;

use socketcan::id::ERR_MASK_ALL;
use socketcan::nl::CanState;
use socketcan::{CanAnyFrame, CanDataFrame, CanFdSocket, CanInterface, Socket, SocketOptions};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

/// An open, non-blocking CAN socket bound to one interface.
#[derive(Debug)]
pub struct CanLink {
    fd: AsyncFd<CanFdSocket>,
}

impl CanLink {
    /// Open a raw CAN socket on `interface`: non-blocking, all frames, all error classes.
    ///
    /// Fails if the interface does not exist (`ENODEV`), is not a CAN interface, or is down
    /// (`ENETDOWN`: the kernel accepts the bind but flags the socket; the flag is checked
    /// here so a down interface is an open failure, not a short-lived "up").
    pub fn open(interface: &str) -> io::Result<CanLink> {
        let sock = CanFdSocket::open(interface)?;
        sock.set_nonblocking(true)?;
        sock.set_filter_accept_all()?;
        sock.set_error_filter(ERR_MASK_ALL)?;
        if let Some(e) = sock.as_raw_socket().take_error()? {
            return Err(e);
        }
        // SAFETY: the socket owns its descriptor, which stays open and unchanged until the
        // AsyncFd (which owns the socket) is dropped.
        let fd = unsafe { AsyncFd::register_with_interest(sock, Interest::READABLE) }?;
        Ok(CanLink { fd })
    }

    /// Next frame of any kind. Waits for data or for a socket error, which is returned.
    pub async fn recv(&self) -> io::Result<CanAnyFrame> {
        self.fd
            .async_io(Interest::READABLE | Interest::ERROR, |s| s.read_frame())
            .await
    }

    /// Write a classic frame without waiting: a full queue comes back at once as `ENOBUFS`
    /// or `WouldBlock` (the bus task counts those and drops the frame).
    pub fn send(&self, frame: &CanDataFrame) -> io::Result<()> {
        self.fd.get_ref().write_frame(frame)
    }
}

/// The CAN controller state the driver reports over netlink (`ip -details link show`):
/// `None` for drivers without one (vcan) or if the query fails. One netlink round trip.
pub(crate) fn controller_state(interface: &str) -> Option<CanState> {
    match CanInterface::open(interface).and_then(|i| i.state()) {
        Ok(state) => state,
        Err(e) => {
            tracing::debug!(target: "can", interface, error = %e, "no CAN state over netlink");
            None
        }
    }
}

/// Errors of a write that leave the link usable: the frame is dropped and counted.
/// `ENOBUFS` (device queue full), `EAGAIN` (socket send buffer full), `EINTR`.
pub(crate) fn is_transient_send_error(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
    ) || e.raw_os_error() == Some(libc::ENOBUFS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transient_send_errors() {
        assert!(is_transient_send_error(&io::Error::from_raw_os_error(
            libc::ENOBUFS
        )));
        assert!(is_transient_send_error(&io::Error::from_raw_os_error(
            libc::EAGAIN
        )));
        for errno in [libc::ENETDOWN, libc::ENODEV, libc::ENXIO, libc::EBADF] {
            assert!(
                !is_transient_send_error(&io::Error::from_raw_os_error(errno)),
                "errno {errno}"
            );
        }
    }

    #[test]
    fn opening_a_missing_interface_fails_cleanly() {
        // No such interface (and, on kernels without CAN, no AF_CAN at all): an error, no panic.
        let e = CanLink::open("nocan9").expect_err("no such interface");
        assert!(e.raw_os_error().is_some(), "{e}");
    }
}
