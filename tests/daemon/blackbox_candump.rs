//! Import of a `candump -l` log (tests/fixtures/candump/skid_closure.log) through the signal
//! map and the DBC into `antisurge replay`: the frames decode to the sensor values the skid
//! sent (with their ages on the control tick), damaged frames are dropped as the daemon's CAN
//! task drops them, and the control core replays the inputs — in automatic mode while the
//! pressures arrive, in fail-safe with the recycle valve fully open once they have stopped for
//! their timeout and the failure hold.
//!
//! The fixture is written by `fixture_frames` below (the simulated kvangardsnes skid at 100 Hz
//! through a throttle closure, encoded by the skid's own encoder); regenerate it with
//! `cargo test --release --test daemon -- --ignored blackbox_candump::write_fixture`.

use crate::common;

use antisurge::blackbox::{candump, replay};
use antisurge::daemon::{config, service};
use antisurge::io::can::bus::BusCodec;
use antisurge::io::can::dbc::FrameId;
use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::vocab::signals::{ActuatorCommands, ActuatorId, SensorId, SensorSnapshot};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Sensor frames every 10 ms, 0.3 ms after the tick; the pressures stop after this many.
const BURSTS: usize = 80;
const PRESSURE_BURSTS: usize = 35;
const BURST_PERIOD_S: f64 = 0.010;
const T0_S: u64 = 1_764_000_000;

fn fixture() -> PathBuf {
    common::root().join("tests/fixtures/candump/skid_closure.log")
}

/// A field config of the shipped skid (signals.toml, skid.dbc) on kvangardsnes, recycle-pi.
fn config(dir: &Path) -> PathBuf {
    let cfg = dir.join("antisurge.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"[plant]
file = "{plant}"
[control]
law = "recycle-pi"
mode = "auto"
failsafe_recycle_opening_pct = 100.0
startup_grace_ms = 100.0
[cycle]
rate_hz = 1000.0
lock_memory = false
[bus]
transport = "field"
signal_map = "{map}"
[bus.can]
interface = "can0"
dbc = "{dbc}"
[event_log]
path = "{events}"
"#,
            plant = common::daemon::shipped("plants/kvangardsnes2009_recycle.toml"),
            map = common::daemon::shipped("signals.toml"),
            dbc = common::daemon::shipped("skid.dbc"),
            events = dir.join("events.jsonl").display(),
        ),
    )
    .expect("write config");
    cfg
}

fn codec(l: &config::Loaded) -> BusCodec {
    BusCodec::load(
        Path::new(&common::daemon::shipped("skid.dbc")),
        &l.signal_map.can_bindings(),
    )
    .expect("codec")
}

/// The skid's sensor values at each burst: the plant stepped through a 60 → 45 % throttle
/// closure over the first half second.
fn sensor_values() -> Vec<SensorSnapshot> {
    let desc = common::plant("kvangardsnes2009_recycle");
    let init = desc.file.initial;
    let mut inputs = PlantInputs {
        throttle_process: init.throttle,
        recycle_manual: init.recycle_valve,
        feed: init.feed,
        ..Default::default()
    };
    let mut plant = SimPlant::new(&desc, &inputs).expect("plant");
    let mut out = Vec::new();
    for _ in 0..BURSTS {
        out.push(plant.sensors());
        for _ in 0..10 {
            inputs.throttle_process = (inputs.throttle_process - 0.0003).max(0.45);
            plant.step(&inputs, 0.001);
        }
    }
    out
}

fn hex(data: &[u8]) -> String {
    data.iter().map(|b| format!("{b:02X}")).collect()
}

fn line(out: &mut String, t_s: f64, iface: &str, id: FrameId, data: &[u8]) {
    let ns = (t_s * 1e9).round() as u64;
    let (s, us) = (T0_S + ns / 1_000_000_000, (ns % 1_000_000_000) / 1000);
    let id = match id {
        FrameId::Standard(v) => format!("{v:03X}"),
        FrameId::Extended(v) => format!("{v:08X}"),
    };
    let _ = writeln!(out, "({s}.{us:06}) {iface} {id}#{}", hex(data));
}

/// The log's text: sensor frames and the running controller's commands, plus one frame of
/// each kind the receive path must drop or skip.
fn fixture_text(codec: &BusCodec) -> String {
    let c = &codec.frames;
    let values = sensor_values();
    let msg = |n: &str| c.message_index(n).expect(n);
    let sensors = [
        msg("PLANT_Pressures"),
        msg("PLANT_SpeedFlowTemp"),
        msg("PLANT_Positions"),
        msg("PLANT_Drive"),
    ];
    let cmd1 = msg("CTRL_ActuatorCmd1");
    let mut alive = c.alive_counters();
    let mut out = String::from(
        "# candump -l of the simulated kvangardsnes skid (tests/daemon/blackbox_candump.rs)\n",
    );
    for (k, v) in values.iter().enumerate() {
        // the controller that was running: its recycle valve command at the tick …
        let mut cmd = ActuatorCommands::default();
        cmd.set(ActuatorId::RecycleValve, 0.001 * k as f64);
        let e = c
            .encode(cmd1, &cmd, alive.next_value(cmd1))
            .expect("encode");
        line(
            &mut out,
            k as f64 * BURST_PERIOD_S,
            "can0",
            e.id,
            e.payload(),
        );
        // … and the skid's sensor frames 0.3 ms later
        let t = k as f64 * BURST_PERIOD_S + 0.0003;
        for (i, &m) in sensors.iter().enumerate() {
            if i == 0 && k >= PRESSURE_BURSTS {
                continue; // the pressure transmitters' frames stop
            }
            let a = alive.next_value(m);
            let e = c.encode(m, v, a).expect("encode");
            line(&mut out, t + i as f64 * 1e-5, "can0", e.id, e.payload());
            if k == 25 && i == 1 {
                // the same frame again: a stuck sender (alive counter repeated), dropped
                line(&mut out, t + 1.5e-5, "can0", e.id, e.payload());
            }
        }
        if k == 20 {
            // a damaged pressure frame: 1 Pa in it, CRC wrong; dropped
            let mut bad = *v;
            bad.set(SensorId::PSuction, 1.0);
            let e = c.encode(sensors[0], &bad, 0).expect("encode");
            let mut d = e.payload().to_vec();
            d[7] ^= 0x5A;
            line(&mut out, t + 5e-5, "can0", e.id, &d);
            line(
                &mut out,
                t + 6e-5,
                "can0",
                FrameId::Standard(0x7F0),
                &[1, 2, 3],
            );
            let _ = writeln!(out, "({T0_S}.{:06}) can0 123#R", (t * 1e6) as u64 + 70);
            line(&mut out, t + 8e-5, "can1", e.id, e.payload());
        }
    }
    out
}

#[test]
#[ignore = "writes tests/fixtures/candump/skid_closure.log"]
fn write_fixture() {
    let tmp = tempfile::tempdir().expect("tmp");
    let l = config::load(&config(tmp.path())).unwrap_or_else(|p| panic!("{p:?}"));
    let text = fixture_text(&codec(&l));
    std::fs::create_dir_all(fixture().parent().unwrap()).expect("dir");
    std::fs::write(fixture(), text).expect("write fixture");
}

#[test]
fn the_fixture_is_what_the_encoder_writes() {
    let tmp = tempfile::tempdir().expect("tmp");
    let l = config::load(&config(tmp.path())).unwrap_or_else(|p| panic!("{p:?}"));
    let on_disk = std::fs::read_to_string(fixture()).expect("fixture");
    let want = fixture_text(&codec(&l));
    let diff = on_disk.lines().zip(want.lines()).position(|(a, b)| a != b);
    assert!(
        diff.is_none() && on_disk.lines().count() == want.lines().count(),
        "line {:?} differs; regenerate: cargo test --release --test daemon -- --ignored blackbox_candump::write_fixture",
        diff.map(|d| d + 1)
    );
}

#[test]
fn a_candump_log_decodes_through_the_signal_map_and_replays_through_the_core() {
    let tmp = tempfile::tempdir().expect("tmp");
    let cfg = config(tmp.path());
    let l = config::load(&cfg).unwrap_or_else(|p| panic!("{p:?}"));
    let frames = candump::read(&fixture()).expect("parse the log");
    let imp = candump::import(
        &frames,
        Arc::new(codec(&l)),
        service::blackbox_header(&l),
        service::operator_inputs(&l),
        None,
        &fixture(),
    )
    .expect("import");
    let st = &imp.stats;
    assert_eq!(st.interface, "can0");
    assert_eq!(st.other_interface, 1);
    let s = &st.sensor_side;
    assert_eq!(
        (s.bad_crc, s.alive_repeated, s.unknown_id, s.remote_frames),
        (1, 1, 1, 1),
        "{s:?}"
    );
    assert_eq!(
        s.rx_published as usize,
        BURSTS * 4 - (BURSTS - PRESSURE_BURSTS)
    );
    assert_eq!(st.command_side.rx_published as usize, BURSTS);

    // one record per 1 ms tick up to the last frame
    let rec = &imp.recording.records;
    assert_eq!(rec.len(), 791, "{} records", rec.len());
    assert_eq!(rec[0].cycle, 0);
    assert!((rec[10].t_s - 0.011).abs() < 1e-12, "{}", rec[10].t_s);
    // values: those of the last frame before each tick, to the DBC's resolution
    let values = sensor_values();
    let res = [
        (SensorId::PSuction, 0.5),
        (SensorId::PDischarge, 0.5),
        (SensorId::ShaftSpeed, 0.025),
        (SensorId::OrificeDp, 0.25),
        (SensorId::TSuction, 0.005),
        (SensorId::ThrottlePosition, 0.5e-4),
    ];
    for r in rec.iter() {
        // frames of burst k arrive 0.3 ms after k·10 ms; tick t sees bursts ≤ (t − 0.3 ms)/10 ms
        let k = (((r.t_s - 0.0003) / BURST_PERIOD_S).floor() as usize).min(BURSTS - 1);
        for (id, tol) in res {
            let got = r.raw.values.get(id);
            if id == SensorId::PSuction || id == SensorId::PDischarge {
                let kp = k.min(PRESSURE_BURSTS - 1);
                let want = values[kp].get(id);
                assert!(
                    (got - want).abs() <= tol + 1e-9,
                    "t {} {id:?}: {got} vs {want}",
                    r.t_s
                );
                assert!(got > 1000.0, "the damaged frame's 1 Pa reached the core");
            } else {
                let want = values[k].get(id);
                assert!(
                    (got - want).abs() <= tol + 1e-9,
                    "t {} {id:?}: {got} vs {want}",
                    r.t_s
                );
            }
        }
    }
    // the age is the tick's time since the frame arrived
    let r = &rec[14]; // t = 15 ms; the burst at 10.3 ms
    assert!((r.raw.age_s[SensorId::PSuction.index()] - 0.0047).abs() < 1e-9);
    assert!((r.raw.age_s[SensorId::ShaftSpeed.index()] - 0.00469).abs() < 1e-9);
    let last = rec.last().unwrap();
    assert!(last.raw.age_s[SensorId::PSuction.index()] > 0.14);
    // the controller's commands seen on the bus
    assert!((last.commands.get(ActuatorId::RecycleValve) - 0.079).abs() < 1e-4);

    // through the core with the configuration's settings
    let r = replay::replay(
        &imp.recording,
        replay::ReplaySetup {
            model: l.model.clone(),
            controller: l.controller.clone(),
            settings: l.core,
            law: l.law,
            recorded_settings: false,
        },
    )
    .expect("replay");
    assert_eq!(r.commands.len(), rec.len());
    // auto while the pressures arrive (after the 100 ms start-up grace) and through the
    // failure hold after their 50 ms timeout …
    let last_pressure_s = (PRESSURE_BURSTS - 1) as f64 * BURST_PERIOD_S + 0.0003;
    let fail_safe_s = last_pressure_s + 0.050 + l.core.failure_hold_s;
    assert!(
        fail_safe_s < rec.last().unwrap().t_s - 0.05,
        "the log is long enough"
    );
    for (x, (c, mode)) in rec.iter().zip(&r.commands) {
        if x.t_s > 0.15 && x.t_s < fail_safe_s - 0.005 {
            assert_eq!(*mode, 2, "t {}: mode {mode}", x.t_s);
            assert!(c.get(ActuatorId::RecycleValve).is_finite());
        }
        // … then fail-safe with the recycle valve open
        if x.t_s > fail_safe_s + 0.005 {
            assert_eq!(*mode, 3, "t {}: mode {mode}", x.t_s);
            assert_eq!(c.get(ActuatorId::RecycleValve), 1.0, "t {}", x.t_s);
        }
    }
}

#[test]
fn antisurge_replay_reads_a_candump_log() {
    let tmp = tempfile::tempdir().expect("tmp");
    let cfg = config(tmp.path());
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["replay", "--candump"])
        .arg(fixture())
        .arg("--config")
        .arg(&cfg)
        .arg("--out")
        .arg(tmp.path().join("pictures"))
        .output()
        .expect("run antisurge replay");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("791 cycles"), "{text}");
    assert!(text.contains("bad CRC 1"), "{text}");
    assert!(text.contains("repeated alive 1"), "{text}");
    // the pictures of the replayed run, beside the commands
    for f in ["commands.csv", "timeseries.svg"] {
        let p = tmp.path().join("pictures").join(f);
        assert!(p.is_file(), "{} missing\n{text}", p.display());
    }
    // a broken line is located
    let bad = tmp.path().join("bad.log");
    std::fs::write(&bad, "(1.000000) can0 100#00\n(1.001000) can0 10#0\n").expect("write");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_antisurge"))
        .args(["replay", "--candump"])
        .arg(&bad)
        .arg("--config")
        .arg(&cfg)
        .output()
        .expect("run antisurge replay");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("bad.log:2:"), "{err}");
}
