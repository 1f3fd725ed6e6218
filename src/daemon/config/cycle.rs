//! `[cycle]`: the control thread (rate, SCHED_FIFO priority, CPU, memory locking). The type
//! is the runtime's own ([`RtSettings`]); its rules as configuration keys are here.

use super::problem::KeyProblem;
use crate::runtime::rt_loop::RtSettings;

/// The rules of `[cycle]` on a machine with `cpus` CPUs.
pub fn validate(c: &RtSettings, cpus: usize) -> Vec<KeyProblem> {
    let mut out = Vec::new();
    if !(c.rate_hz.is_finite() && c.rate_hz > 0.0 && c.rate_hz <= 10_000.0) {
        out.push(
            KeyProblem::error(
                "cycle.rate_hz",
                format!("{} Hz is outside 0 < rate_hz ≤ 10000", c.rate_hz),
            )
            .with_hint("1000 on CAN, 50–100 on Modbus"),
        );
    }
    if let Some(p) = c.priority {
        if !(1..=99).contains(&p) {
            out.push(
                KeyProblem::error(
                    "cycle.priority",
                    format!("{p} is not a SCHED_FIFO priority (1–99)"),
                )
                .with_hint("80 is the usual choice; leave it out for normal scheduling"),
            );
        }
    }
    if let Some(cpu) = c.cpu {
        // the index reaches CPU_SET (unsafe) at start: refuse it here, not with an abort there
        if cpu >= cpus {
            out.push(
                KeyProblem::error(
                    "cycle.cpu",
                    format!(
                        "CPU {cpu} does not exist: this machine has CPUs 0–{}",
                        cpus.saturating_sub(1)
                    ),
                )
                .with_hint("leave it out for no pinning, or name an isolated CPU (isolcpus=)"),
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_priority_and_cpu_name_their_keys() {
        let mut c = RtSettings::default();
        assert!(validate(&c, 2).is_empty());
        c.rate_hz = 0.0;
        c.priority = Some(120);
        c.cpu = Some(2);
        let keys: Vec<String> = validate(&c, 2).into_iter().map(|p| p.key).collect();
        assert_eq!(keys, ["cycle.rate_hz", "cycle.priority", "cycle.cpu"]);
        c.cpu = Some(1);
        assert!(!validate(&c, 2).iter().any(|p| p.key == "cycle.cpu"));
    }
}
