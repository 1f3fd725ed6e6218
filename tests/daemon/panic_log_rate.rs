//! Issue 12, item 9: panic reports are rate-limited. A child process (this test binary,
//! re-run with `PANIC_LOG_CHILD=1`) installs the daemon's hook with 3 reports per second and
//! panics 50 times in a burst, then once more after the window: its stderr must hold 4 reports
//! and one line counting the 47 suppressed.

use std::process::Command;
use std::time::Duration;

#[test]
fn a_panic_burst_prints_at_most_the_limit_and_counts_the_rest() {
    if std::env::var_os("PANIC_LOG_CHILD").is_some() {
        antisurge::runtime::panic_log::install(3, Duration::from_secs(1));
        for i in 0..50 {
            let r = std::panic::catch_unwind(|| panic!("burst panic {i}"));
            assert!(r.is_err());
        }
        std::thread::sleep(Duration::from_millis(1100));
        assert!(std::panic::catch_unwind(|| panic!("after the window")).is_err());
        return;
    }
    let out = Command::new(std::env::current_exe().expect("test binary"))
        .args([
            "--exact",
            &crate::common::own_test_name(
                module_path!(),
                "a_panic_burst_prints_at_most_the_limit_and_counts_the_rest",
            ),
            "--nocapture",
            "--test-threads=1",
        ])
        .env("PANIC_LOG_CHILD", "1")
        .output()
        .expect("child");
    assert!(out.status.success(), "child failed: {out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    let reports: Vec<&str> = err.lines().filter(|l| l.contains("panicked at")).collect();
    assert_eq!(reports.len(), 4, "{err}");
    assert_eq!(err.matches("burst panic").count(), 3, "{err}");
    assert_eq!(err.matches("after the window").count(), 1, "{err}");
    assert!(
        err.contains("antisurge: 47 further panic reports suppressed (at most 3 per 1 s)"),
        "{err}"
    );
}
