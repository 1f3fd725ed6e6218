//! The black box: a daemon run (in-process plant, throttle closure) is recorded, and the
//! recording replayed through the control core reproduces every command bit for bit; with a
//! changed gain the replay shows different commands. `antisurge replay` draws the replayed run
//! (map with the operating-point trail, time series) and, with changed settings, the recorded
//! commands beside the replayed ones.

use crate::common;

use antisurge::blackbox::{self, replay};
use antisurge::daemon::config;
use common::daemon::{shipped, spawn, wait};
use std::time::Duration;

#[test]
fn a_recorded_daemon_run_replays_with_identical_commands() {
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let events = dir.join("events.jsonl");
    let cfg = dir.join("antisurge.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"[plant]
file = "{plant}"
[control]
law = "recycle-pi"
[cycle]
rate_hz = 1000.0
lock_memory = false
[event_log]
path = "{events}"
[simulation]
scenario = "throttle-closure"
"#,
            plant = shipped("plants/kvangardsnes2009_recycle.toml"),
            events = events.display(),
        ),
    )
    .expect("write config");
    let out = dir.join("plant");
    let mut ctl = spawn(
        dir,
        "run",
        &[
            "run",
            "--config",
            &cfg.display().to_string(),
            "--duration-s",
            "8",
            "--out",
            &out.display().to_string(),
        ],
    );
    let status = wait(&mut ctl, Duration::from_secs(60), "antisurge run", dir);
    assert!(status.success(), "{}", common::daemon::logs(dir));
    let bb_dir = dir.join("blackbox");
    let exit_file = std::fs::read_dir(&bb_dir)
        .unwrap_or_else(|e| panic!("{}: {e}\n{}", bb_dir.display(), common::daemon::logs(dir)))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.to_string_lossy().contains("blackbox-exit-"))
        .expect("an exit dump");
    let rec = blackbox::read_file(&exit_file).expect("read the recording");
    assert_eq!(rec.header.law, "recycle-pi");
    assert_eq!(
        rec.records.first().map(|r| r.cycle),
        Some(0),
        "starts at the first cycle"
    );
    // 8 s at 1 kHz, minus start-up: the closure (5–7 s) is in it
    assert!(rec.records.len() > 6000, "{} records", rec.records.len());
    assert!(rec.records.iter().any(|r| r.t_s > 7.0));
    let loaded = config::load(&cfg).unwrap_or_else(|p| panic!("{p:?}"));
    let setup = |controller| replay::ReplaySetup {
        model: loaded.model.clone(),
        controller,
        settings: loaded.core,
        law: loaded.law,
        recorded_settings: true,
    };
    let r = replay::replay(&rec, setup(rec.header.controller.clone())).expect("replay");
    assert_eq!(
        r.report.identical_cycles, r.report.cycles,
        "{:#?}",
        r.report
    );
    assert!(r.report.updates_at_cycles.is_empty());
    eprintln!(
        "replayed {} cycles, {} identical",
        r.report.cycles, r.report.identical_cycles
    );

    // a different gain commands something else over the same inputs
    let mut other = rec.header.controller.clone();
    other.recycle_pi.pi.kp_per_map_flow *= 3.0;
    let changed = replay::replay(&rec, setup(other)).expect("replay");
    assert!(
        changed.report.identical_cycles < changed.report.cycles,
        "{:#?}",
        changed.report
    );

    // and the command line says the same, with exit status 0, and draws the replayed run
    let pics = dir.join("replay-recorded");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .current_dir(dir)
        .args(["replay", &exit_file.display().to_string(), "--out"])
        .arg(&pics)
        .output()
        .expect("antisurge replay");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        text.contains(&format!(
            "{0} of {0} cycles bit-identical",
            rec.records.len()
        )),
        "{text}"
    );

    assert!(text.contains("timeseries.svg"), "{text}");
    // the map with the operating-point trail over the closure, the time series with the
    // margin panel; the commands are the recorded ones: no comparison drawn
    let map = read_svg(&pics.join("map.svg"));
    assert!(has_text(&map, "operating point"), "no trail in the legend");
    let trail = longest_polyline(&map, TRAJ_STROKE);
    assert!(trail > 50, "operating-point trail of {trail} points");
    let ts = read_svg(&pics.join("timeseries.svg"));
    for label in [
        "surge margin",
        "recycle valve command",
        "recycle valve position",
    ] {
        assert!(has_text(&ts, label), "timeseries.svg lacks {label:?}");
    }
    assert!(!ts.contains("(recorded)"));
    assert!(std::fs::read_to_string(pics.join("commands.csv"))
        .expect("commands.csv")
        .starts_with("t_s,mode_recorded,mode_replayed"));

    // with a changed gain (another config): the recorded commands beside the replayed ones
    let kp = rec.header.controller.recycle_pi.pi.kp_per_map_flow * 3.0;
    let cfg2 = dir.join("candidate.toml");
    let text1 = std::fs::read_to_string(&cfg).expect("config");
    std::fs::write(
        &cfg2,
        format!("{text1}[controller.recycle_pi.pi]\nkp_per_map_flow = {kp:?}\n"),
    )
    .expect("write candidate");
    let pics2 = dir.join("replay-changed");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .current_dir(dir)
        .args(["replay", &exit_file.display().to_string(), "--config"])
        .arg(&cfg2)
        .arg("--out")
        .arg(&pics2)
        .output()
        .expect("antisurge replay");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(text.contains("settings        changed"), "{text}");
    let ts = read_svg(&pics2.join("timeseries.svg"));
    for label in [
        "recycle valve command",
        "recycle valve command (recorded)",
        "surge margin",
    ] {
        assert!(has_text(&ts, label), "timeseries.svg lacks {label:?}");
    }
    let recorded = longest_polyline(&ts, RECORDED_STROKE);
    assert!(recorded > 50, "recorded command trace of {recorded} points");
    let map = read_svg(&pics2.join("map.svg"));
    assert!(longest_polyline(&map, TRAJ_STROKE) > 50);
}

/// Stroke of the map's operating-point trail (`plot::map`'s TRAJ_COLOR).
const TRAJ_STROKE: &str = "#1F6EBE";
/// Stroke of recorded commands beside replayed ones (`plot::timeseries`'s RECORDED_COLOR).
const RECORDED_STROKE: &str = "#282828";

fn read_svg(path: &std::path::Path) -> String {
    let s = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(s.starts_with("<svg") && s.trim_end().ends_with("</svg>"));
    s
}

/// Whether some `<text>` element reads exactly `label`.
fn has_text(svg: &str, label: &str) -> bool {
    svg.split("<text").skip(1).any(|t| {
        t.find('>')
            .map(|k| &t[k + 1..])
            .and_then(|b| b.find("</text>").map(|e| b[..e].trim() == label))
            .unwrap_or(false)
    })
}

/// Points of the longest polyline stroked in `stroke`.
fn longest_polyline(svg: &str, stroke: &str) -> usize {
    let stroke = format!("stroke=\"{stroke}\"");
    svg.lines()
        .filter(|l| l.contains("<polyline") && l.contains(&stroke))
        .map(|l| {
            l.split("points=\"")
                .nth(1)
                .and_then(|p| p.split('"').next())
                .map_or(0, |p| p.split_whitespace().count())
        })
        .max()
        .unwrap_or(0)
}
