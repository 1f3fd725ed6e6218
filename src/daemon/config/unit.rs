//! What the shipped systemd unit lets the service do, for `check-config`.
//!
//! The unit (`deploy/antisurge.service`, embedded here at build time so the two cannot
//! drift) runs the daemon as an unprivileged user with only the capabilities in its
//! `AmbientCapabilities=`. Binding a TCP port below the kernel's
//! `net.ipv4.ip_unprivileged_port_start` (1024 by default) needs `CAP_NET_BIND_SERVICE`,
//! which the shipped unit does not grant: `modbus_listen = "0.0.0.0:502"` would pass every
//! other check and then fail to bind at start. [`bind_problems`] refuses such an address
//! unless a drop-in of the installed unit grants the capability.

use std::collections::BTreeSet;
use std::net::SocketAddr;
use std::path::Path;

use super::problem::KeyProblem;
use super::StatusSection;

/// The shipped unit file, as built into this binary.
pub const SHIPPED_UNIT: &str = include_str!("../../../deploy/antisurge.service");

/// Where drop-ins of the installed unit live (`systemctl edit antisurge`, the package's).
pub const DROP_IN_DIRS: [&str; 3] = [
    "/etc/systemd/system/antisurge.service.d",
    "/run/systemd/system/antisurge.service.d",
    "/usr/lib/systemd/system/antisurge.service.d",
];

/// The capability a port below the unprivileged range needs.
pub const NET_BIND: &str = "CAP_NET_BIND_SERVICE";

/// The values of `key=` in unit texts, applied in order: a list adds, an empty assignment
/// empties (systemd's rule for `AmbientCapabilities=` and `CapabilityBoundingSet=`).
pub fn unit_list<'a>(texts: impl IntoIterator<Item = &'a str>, key: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for text in texts {
        for line in text.lines().map(str::trim) {
            let Some(value) = line
                .strip_prefix(key)
                .and_then(|r| r.trim_start().strip_prefix('='))
            else {
                continue;
            };
            let value = value.trim();
            if value.is_empty() {
                out.clear();
            } else {
                out.extend(value.split_whitespace().map(str::to_string));
            }
        }
    }
    out
}

/// Whether units with these texts (the unit, then its drop-ins) give the service
/// `CAP_NET_BIND_SERVICE`: in `AmbientCapabilities=` and not kept out by
/// `CapabilityBoundingSet=`.
pub fn grants_net_bind(texts: &[&str]) -> bool {
    let ambient = unit_list(texts.iter().copied(), "AmbientCapabilities");
    let bounding = unit_list(texts.iter().copied(), "CapabilityBoundingSet");
    ambient.contains(NET_BIND) && (bounding.is_empty() || bounding.contains(NET_BIND))
}

/// The installed drop-ins' texts, in file-name order per directory.
fn drop_ins() -> Vec<String> {
    let mut out = Vec::new();
    for dir in DROP_IN_DIRS {
        let Ok(rd) = std::fs::read_dir(Path::new(dir)) else {
            continue;
        };
        let mut files: Vec<_> = rd
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "conf"))
            .collect();
        files.sort();
        out.extend(files.iter().filter_map(|p| std::fs::read_to_string(p).ok()));
    }
    out
}

/// The lowest port an unprivileged process may bind (`net.ipv4.ip_unprivileged_port_start`,
/// 1024 when it cannot be read).
pub fn unprivileged_port_start() -> u16 {
    std::fs::read_to_string("/proc/sys/net/ipv4/ip_unprivileged_port_start")
        .ok()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(1024)
}

/// The listen addresses of `status` (key, text), set and not empty.
fn listen_keys(status: &StatusSection) -> Vec<(&'static str, &str)> {
    [
        ("status.modbus_listen", status.modbus_listen.as_deref()),
        ("status.hmi_listen", status.hmi_listen.as_deref()),
        ("status.metrics_listen", status.metrics_listen.as_deref()),
    ]
    .into_iter()
    .filter_map(|(k, v)| Some((k, v?.trim())))
    .filter(|(_, v)| !v.is_empty())
    .collect()
}

/// Listen addresses the service could not bind under the unit (`unit_texts`: the unit and its
/// drop-ins; `port_start`: the unprivileged range's start). Also refuses a
/// `modbus_listen` that is not `host:port`.
pub fn bind_problems_with(
    status: &StatusSection,
    unit_texts: &[&str],
    port_start: u16,
) -> Vec<KeyProblem> {
    let mut out = Vec::new();
    for (key, text) in listen_keys(status) {
        let addr: SocketAddr = match text.parse() {
            Ok(a) => a,
            Err(e) => {
                // the HMI and metrics addresses have their own rules with their own messages
                if key == "status.modbus_listen" {
                    out.push(
                        KeyProblem::error(key, format!("`{text}`: {e} (expected host:port)"))
                            .with_hint("e.g. modbus_listen = \"0.0.0.0:1502\""),
                    );
                }
                continue;
            }
        };
        let port = addr.port();
        if port != 0 && port < port_start && !grants_net_bind(unit_texts) {
            out.push(
                KeyProblem::error(
                    key,
                    format!(
                        "port {port} is below {port_start} (net.ipv4.ip_unprivileged_port_start) and the service unit runs unprivileged: its AmbientCapabilities= ({}) has no {NET_BIND}, so binding {addr} would fail at start",
                        unit_list(unit_texts.iter().copied(), "AmbientCapabilities")
                            .into_iter()
                            .collect::<Vec<_>>()
                            .join(" ")
                    ),
                )
                .with_hint(format!(
                    "use a port ≥ {port_start} (e.g. 1502, with the DCS pointed at it or a firewall redirect from {port}), or grant it in a drop-in (systemctl edit antisurge): AmbientCapabilities={NET_BIND} and CapabilityBoundingSet={NET_BIND}"
                )),
            );
        }
    }
    out
}

/// [`bind_problems_with`] for the shipped unit, the installed drop-ins and this kernel.
pub fn bind_problems(status: &StatusSection) -> Vec<KeyProblem> {
    let drop_ins = drop_ins();
    let mut texts = vec![SHIPPED_UNIT];
    texts.extend(drop_ins.iter().map(String::as_str));
    bind_problems_with(status, &texts, unprivileged_port_start())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status(modbus: &str) -> StatusSection {
        StatusSection {
            modbus_listen: Some(modbus.into()),
            ..StatusSection::default()
        }
    }

    #[test]
    fn the_shipped_unit_grants_no_privileged_port() {
        // in sync with deploy/antisurge.service (embedded): if the unit ever grants
        // CAP_NET_BIND_SERVICE, this fails and the rule and README need a look
        assert!(!grants_net_bind(&[SHIPPED_UNIT]));
        assert_eq!(
            unit_list([SHIPPED_UNIT], "AmbientCapabilities"),
            BTreeSet::from(["CAP_IPC_LOCK".to_string(), "CAP_SYS_NICE".to_string()])
        );
        let p = bind_problems_with(&status("0.0.0.0:502"), &[SHIPPED_UNIT], 1024);
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].key, "status.modbus_listen");
        assert!(
            p[0].message.contains("AmbientCapabilities"),
            "{}",
            p[0].message
        );
        assert!(p[0].hint.as_deref().is_some_and(|h| h.contains(NET_BIND)));
        assert!(bind_problems_with(&status("0.0.0.0:1502"), &[SHIPPED_UNIT], 1024).is_empty());
        // a kernel that lets everyone bind low ports
        assert!(bind_problems_with(&status("0.0.0.0:502"), &[SHIPPED_UNIT], 0).is_empty());
        assert_eq!(
            bind_problems_with(&status("port 502"), &[SHIPPED_UNIT], 1024)[0].key,
            "status.modbus_listen"
        );
    }

    #[test]
    fn a_drop_in_can_grant_it_and_an_empty_assignment_resets() {
        let grant = "[Service]\nAmbientCapabilities=CAP_NET_BIND_SERVICE\nCapabilityBoundingSet=CAP_NET_BIND_SERVICE\n";
        assert!(grants_net_bind(&[SHIPPED_UNIT, grant]));
        assert!(
            bind_problems_with(&status("0.0.0.0:502"), &[SHIPPED_UNIT, grant], 1024).is_empty()
        );
        // ambient without the bounding set: still refused
        let half = "[Service]\nAmbientCapabilities=CAP_NET_BIND_SERVICE\n";
        assert!(!grants_net_bind(&[SHIPPED_UNIT, half]));
        let reset = "[Service]\nAmbientCapabilities=\n";
        assert!(!grants_net_bind(&[SHIPPED_UNIT, grant, reset]));
    }
}
