//! Issue 25, item 7: the journal fields as documented, read back through journald's native
//! protocol by an independent reader.
//!
//! The daemon runs as under systemd (`JOURNAL_STREAM` set), its journal writer pointed at a
//! datagram socket this test binds in a temporary directory (`ANTISURGE_JOURNAL_SOCKET`, see
//! `antisurge::events::journald`). The test parses every datagram itself — `KEY=value\n`
//! lines and the binary form `KEY\n<u64 LE length><data>\n` — and matches entries the way
//! `journalctl FIELD=value` does. A scenario drives the discharge pressure transmitter to
//! 5e7 Pa (out of its 1e4 … 1.2e7 Pa range): the fail-safe must be found by the documented
//! `journalctl -u antisurge INPUT=p_discharge` match, with the documented cause fields.

use crate::common;

use common::daemon::{embedded_config, signal, wait, write_atomically};
use std::collections::BTreeMap;
use std::os::unix::net::UnixDatagram;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// One journal entry: field name → values (a field may repeat).
type Entry = BTreeMap<String, Vec<Vec<u8>>>;

/// Parse one native-protocol datagram. Panics on anything malformed: the writer under test
/// must produce what journald accepts.
fn parse(d: &[u8]) -> Entry {
    let mut e = Entry::new();
    let mut i = 0;
    while i < d.len() {
        let nl = d[i..]
            .iter()
            .position(|&b| b == b'\n')
            .map(|p| i + p)
            .unwrap_or_else(|| panic!("field without a line end at {i}: {d:?}"));
        let line = &d[i..nl];
        let (name, value) = match line.iter().position(|&b| b == b'=') {
            Some(eq) => {
                i = nl + 1;
                (&line[..eq], line[eq + 1..].to_vec())
            }
            None => {
                // binary form: the name, then a little-endian u64 length, the data and '\n'
                let len_at = nl + 1;
                let len = u64::from_le_bytes(
                    d.get(len_at..len_at + 8)
                        .expect("length")
                        .try_into()
                        .expect("8 bytes"),
                ) as usize;
                let data = &d[len_at + 8..len_at + 8 + len];
                assert_eq!(
                    d[len_at + 8 + len],
                    b'\n',
                    "binary field not ended by a line break"
                );
                i = len_at + 8 + len + 1;
                (line, data.to_vec())
            }
        };
        let name = std::str::from_utf8(name).expect("utf-8 name").to_string();
        // journald's rule for a field a client may send
        assert!(
            !name.is_empty()
                && name.len() <= 64
                && !name.starts_with('_')
                && !name.starts_with(|c: char| c.is_ascii_digit())
                && name
                    .chars()
                    .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_'),
            "not a valid journal field name: {name:?}"
        );
        e.entry(name).or_default().push(value);
    }
    e
}

/// The first value of a field as text.
fn get<'a>(e: &'a Entry, k: &str) -> Option<&'a str> {
    e.get(k)
        .and_then(|v| v.first())
        .map(|v| std::str::from_utf8(v).expect("utf-8 value"))
}

/// `journalctl FIELD=value …` semantics: every match must hold (exact value).
fn matches(e: &Entry, terms: &[(&str, &str)]) -> bool {
    terms.iter().all(|(k, v)| {
        e.get(*k)
            .is_some_and(|vs| vs.iter().any(|x| x == v.as_bytes()))
    })
}

#[test]
fn the_parser_reads_both_forms() {
    let mut d = b"MESSAGE\n".to_vec();
    d.extend_from_slice(&5u64.to_le_bytes());
    d.extend_from_slice(b"a\nb=c\nINPUT=p_discharge\n");
    let e = parse(&d);
    assert_eq!(get(&e, "MESSAGE"), Some("a\nb=c"));
    assert_eq!(get(&e, "INPUT"), Some("p_discharge"));
}

#[test]
fn a_fail_safe_writes_the_documented_journal_fields() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let sock_path = dir.join("journal.sock");
    let sock = UnixDatagram::bind(&sock_path).expect("bind the journal socket");
    sock.set_read_timeout(Some(Duration::from_millis(200)))
        .expect("timeout");
    let scenario = dir.join("pd_fault.toml");
    std::fs::write(
        &scenario,
        "name = \"pd-fault\"\ndescription = \"p_discharge reads 5e7 Pa from 3 s\"\nduration_s = 20.0\n\
         [initial]\nthrottle = 0.6\n[[event]]\nat_s = 3.0\n\
         sensor_fault = { sensor = \"p_discharge\", fault = \"value\", value = 5.0e7 }\n",
    )
    .expect("scenario");
    let cfg = dir.join("antisurge.toml");
    let text = embedded_config(
        dir,
        &scenario.display().to_string(),
        "",
        "[reload]\nwatch_files = false\n[inputs.p_discharge]\nmin = 1.0e4\nmax = 1.2e7\ntimeout_ms = 200.0\n",
    );
    std::fs::write(&cfg, &text).expect("config");
    let log = std::fs::File::create(dir.join("run.log")).expect("log");
    let mut d = Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["run", "--config"])
        .arg(&cfg)
        .env("JOURNAL_STREAM", "8:12345")
        .env("ANTISURGE_JOURNAL_SOCKET", &sock_path)
        .env("ANTISURGE_LOG", "info")
        .env_remove("LOGS_DIRECTORY")
        .env_remove("STATE_DIRECTORY")
        .env("ANTISURGE_STATUS__STATE_DIR", dir.join("state"))
        .stdout(Stdio::from(log.try_clone().expect("clone")))
        .stderr(Stdio::from(log))
        .spawn()
        .expect("spawn");

    let mut entries: Vec<Entry> = Vec::new();
    let mut buf = vec![0u8; 1 << 17];
    let t0 = Instant::now();
    let fail_safe = [("EVENT", "mode_changed"), ("TO", "fail_safe")];
    let mut reloaded = false;
    while t0.elapsed() < Duration::from_secs(60) {
        if let Ok(n) = sock.recv(&mut buf) {
            entries.push(parse(&buf[..n]));
        }
        // once in fail-safe: a reload of a bad file (its multi-line reason travels in the
        // binary form)
        if !reloaded && entries.iter().any(|e| matches(e, &fail_safe)) {
            write_atomically(&cfg, &text.replace("\"recycle-pi\"", "\"no-such-law\""));
            signal(&d, libc::SIGHUP);
            reloaded = true;
        }
        if entries
            .iter()
            .any(|e| get(e, "MESSAGE").is_some_and(|m| m.contains("reload rejected")))
        {
            break;
        }
    }
    signal(&d, libc::SIGTERM);
    let st = wait(&mut d, Duration::from_secs(30), "controller", dir);
    assert!(st.success(), "exit {st:?}");
    while let Ok(n) = sock.recv(&mut buf) {
        entries.push(parse(&buf[..n]));
    }
    let dump = || {
        entries
            .iter()
            .map(|e| {
                format!("{:?}", e.keys().collect::<Vec<_>>())
                    + " "
                    + get(e, "MESSAGE").unwrap_or("")
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert!(entries.len() > 3, "too few journal entries:\n{}", dump());

    // the documented match (README.md and the operator guide) finds the fail-safe
    let readme = ["README.md", "docs/operator-guide.md"]
        .iter()
        .map(|f| std::fs::read_to_string(common::root().join(f)).expect(f))
        .collect::<Vec<_>>()
        .join("\n");
    let documented: Vec<(String, String)> = readme
        .split("journalctl -u antisurge ")
        .skip(1)
        .filter_map(|rest| {
            let word = rest
                .split(|c: char| c.is_whitespace() || c == '`' || c == ')')
                .next()?;
            let (k, v) = word.split_once('=')?;
            Some((k.to_string(), v.to_string()))
        })
        .collect();
    assert!(
        documented.contains(&("INPUT".into(), "p_discharge".into())),
        "the documented journalctl example changed: {documented:?}"
    );
    for (k, v) in &documented {
        let hit = entries
            .iter()
            .filter(|e| matches(e, &[(k.as_str(), v.as_str())]))
            .count();
        assert!(
            hit > 0,
            "`journalctl -u antisurge {k}={v}` (README.md / docs/operator-guide.md) matches nothing:\n{}",
            dump()
        );
    }
    let e = entries
        .iter()
        .find(|e| {
            matches(
                e,
                &[
                    ("INPUT", "p_discharge"),
                    ("EVENT", "mode_changed"),
                    ("TO", "fail_safe"),
                ],
            )
        })
        .unwrap_or_else(|| panic!("no fail-safe entry with INPUT=p_discharge:\n{}", dump()));
    // the documented cause fields (src/events/journal.rs, docs/operator-guide.md "Causes") with their values
    assert_eq!(get(e, "PRIORITY"), Some("3"), "{e:?}"); // ERROR: to fail-safe
    assert_eq!(get(e, "FROM"), Some("auto"), "{e:?}");
    assert_eq!(get(e, "CAUSE"), Some("input_fault"), "{e:?}");
    assert_eq!(get(e, "FAULT"), Some("out_of_range"), "{e:?}");
    let num = |k: &str| -> f64 {
        get(e, k)
            .unwrap_or_else(|| panic!("no {k} in {e:?}"))
            .parse()
            .unwrap_or_else(|_| panic!("{k} not a number in {e:?}"))
    };
    assert_eq!(num("VALUE"), 5.0e7);
    assert_eq!(num("MIN"), 1.0e4);
    assert_eq!(num("MAX"), 1.2e7);
    assert_eq!(get(e, "SYSLOG_IDENTIFIER"), Some("antisurge"));
    assert_eq!(get(e, "TARGET"), Some("event"));
    let msg = get(e, "MESSAGE").expect("MESSAGE");
    assert!(
        msg.contains("auto → fail_safe") && msg.contains("p_discharge"),
        "{msg}"
    );
    // no prefixed duplicates (the old layer's F_INPUT)
    assert!(
        entries
            .iter()
            .all(|e| !e.contains_key("F_INPUT") && !e.contains_key("F_EVENT")),
        "prefixed fields:\n{}",
        dump()
    );
    // a multi-line message arrives whole (binary form)
    let rejected = entries
        .iter()
        .filter_map(|e| get(e, "MESSAGE"))
        .find(|m| m.contains("reload rejected"))
        .unwrap_or_else(|| panic!("no reload refusal in the journal:\n{}", dump()));
    assert!(
        rejected.contains('\n') && rejected.contains("no-such-law"),
        "{rejected}"
    );
}
