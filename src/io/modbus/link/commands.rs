//! `command_connection = "own"`: the link's commands and their read-backs on a second TCP
//! connection, so that a command never queues behind a read on a device that answers one
//! connection's requests one after the other ([`super::CommandConnection`]).
//!
//! Two tasks of one link, one [`super::Controller`] each: the read side polls at the link
//! period and reports the link's state for both (a failed command connection is the link
//! down, with its cause); the command side writes each new output set as soon as the control
//! cycle has computed it from the latest read, and the read-backs after its writes (so a
//! read-back still sees this controller's last write unless another master wrote since).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::time::Instant;

use super::{Controller, LinkState, Outcome, Role};
use crate::io::modbus::client::ClientCounters;
use crate::runtime::handoff::monotonic_ns;

/// What the two sides of a split link share. The locks are held for a copy, on the bus
/// threads only (never the control thread).
#[derive(Debug, Default)]
pub(super) struct Split {
    /// When the read side last published values (monotonic ns; 0: never).
    pub(super) read_done_ns: AtomicU64,
    /// When the command connection last failed (monotonic ns; 0: never).
    command_failed_ns: AtomicU64,
    /// The command connection's state while it is down.
    commands_down: Mutex<Option<LinkState>>,
    /// The command connection's client counters.
    command_counters: Mutex<ClientCounters>,
}

impl Split {
    pub(super) fn note_command_failure(&self, now_ns: u64) {
        self.command_failed_ns.store(now_ns, Ordering::Release);
    }

    pub(super) fn set_commands_down(&self, state: Option<LinkState>) {
        *self.commands_down.lock().unwrap_or_else(|e| e.into_inner()) = state;
    }

    pub(super) fn commands_down(&self) -> Option<LinkState> {
        *self.commands_down.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub(super) fn set_command_counters(&self, k: ClientCounters) {
        *self
            .command_counters
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = k;
    }

    pub(super) fn command_counters(&self) -> ClientCounters {
        *self
            .command_counters
            .lock()
            .unwrap_or_else(|e| e.into_inner())
    }
}

/// Both connections' client counters, summed.
pub(super) fn add_counters(a: ClientCounters, b: ClientCounters) -> ClientCounters {
    ClientCounters {
        requests: a.requests + b.requests,
        timeouts: a.timeouts + b.timeouts,
        exceptions: a.exceptions + b.exceptions,
        transport_errors: a.transport_errors + b.transport_errors,
        protocol_errors: a.protocol_errors + b.protocol_errors,
        connect_attempts: a.connect_attempts + b.connect_attempts,
        connect_failures: a.connect_failures + b.connect_failures,
        reconnects: a.reconnects + b.reconnects,
        clamped_values: a.clamped_values + b.clamped_values,
        cancelled: a.cancelled + b.cancelled,
    }
}

/// Split `reads` (a link built from the whole map) into its read side and a command side on
/// a connection of its own (`command`, built from the same configuration and map). Both share
/// one [`Split`].
pub(super) fn split(reads: &mut Controller, mut command: Controller) -> Controller {
    let shared = Arc::new(Split::default());
    // the read side: no commands, no read-backs, no heartbeat or watchdog words
    reads.write_plan = super::WritePlan::new(&[]).expect("an empty write plan is valid");
    reads.write_values.clear();
    reads.readbacks.clear();
    reads.heartbeat = false;
    reads.watchdog = None;
    reads.role = Role::Reads;
    reads.split = Some(Arc::clone(&shared));
    // the command side: no reads and no cycle trigger
    command.groups.clear();
    command.trigger = None;
    command.role = Role::Commands;
    command.split = Some(shared);
    command
}

/// How often the command side looks for a new output set: 1 ms, tokio's timer resolution
/// (a control cycle at 1 kHz publishes one set per ms).
const LOOK_EVERY: Duration = Duration::from_millis(1);

impl Controller {
    /// Whether the command side has something to send now (`last` = when it last sent and
    /// the read side's latest read then): a read-back that is due; the output set computed
    /// from a read that came since (the answer to fresh values goes out at once); or, a link
    /// period after the last send, any new set (the control thread's own deadline cycles, a
    /// fail-safe while reads fail). So commands go out at most once per read plus once per
    /// link period, never at the control rate.
    fn command_due(&self, last: (u64, u64)) -> bool {
        let now = monotonic_ns();
        if !self.readbacks.is_empty() && now >= self.next_readback_ns {
            return true;
        }
        let Some(o) = self.outputs.latest() else {
            return false;
        };
        if self.last_written_cycle == Some(o.cycle) {
            return false;
        }
        let read_ns = self.latest_read_ns();
        let (last_sent_ns, last_read_ns) = last;
        (read_ns > last_read_ns && o.t_ns >= read_ns)
            || now.saturating_sub(last_sent_ns) >= self.period_ns
    }

    /// When the read side last published values (monotonic ns; 0: never).
    fn latest_read_ns(&self) -> u64 {
        self.split
            .as_ref()
            .map_or(0, |sp| sp.read_done_ns.load(Ordering::Acquire))
    }

    /// After a failure of the command connection nothing is written until the control
    /// thread computed a set from values read after it (as on a shared link, see `resync`):
    /// here the values come from the read side.
    fn resync_on_reads(&mut self) {
        if self.resync != Some(None) {
            return;
        }
        let Some(sp) = &self.split else {
            return;
        };
        let read_ns = sp.read_done_ns.load(Ordering::Acquire);
        if read_ns > sp.command_failed_ns.load(Ordering::Acquire) {
            let latest_cycle = self.outputs.latest().map_or(0, |o| o.cycle);
            self.resync = Some(Some(latest_cycle));
            self.resync_read_ns = read_ns;
        }
    }

    /// One command exchange: the latest output set, then a read-back if due.
    async fn command_cycle(&mut self) -> Outcome {
        let mut out = Outcome::default();
        self.resync_on_reads();
        self.write(&mut out).await;
        if !out.link_failed {
            self.read_back(&mut out).await;
        }
        out
    }
}

/// The command side's loop (never returns; the caller selects it against shutdown).
pub(super) async fn run(cmd: &mut Controller, period: Duration) {
    let mut last = (0u64, 0u64);
    loop {
        while !cmd.command_due(last) {
            tokio::time::sleep(LOOK_EVERY).await;
        }
        last = (monotonic_ns(), cmd.latest_read_ns());
        let start = Instant::now();
        let out = cmd.command_cycle().await;
        cmd.finish(&out, start.elapsed(), period);
        if out.link_failed || (out.write.is_none() && !out.answered) {
            // nothing went out (the client's backoff, a resync wait, a stale set): look again
            // in a while instead of spinning on the runtime's thread
            tokio::time::sleep(LOOK_EVERY).await;
        }
    }
}
