//! Socket-free tests of the bus tasks: RX handling into boards and counters, TX encoding from
//! boards, error-frame classification, config, state reporting, and the reconnect loop on an
//! interface that does not exist (works without kernel CAN support).

use super::*;
use crate::io::can::codec::{skid_bindings, MessageIndex};
use crate::io::can::e2e::frame_crc;
use crate::runtime::handoff::{HeartbeatSeen, Outputs, SensorBoard};
use crate::runtime::trigger::CycleTrigger;
use crate::vocab::signals::{ActuatorCommands, ActuatorId, SensorId, SensorSnapshot};
use crate::vocab::Mode;
use socketcan::errors::{ControllerProblems, ErrorCause};
use socketcan::{
    CanAnyFrame, CanDataFrame, CanErrorFrame, CanFdFrame, CanRemoteFrame, EmbeddedFrame, StandardId,
};

fn codec() -> Arc<BusCodec> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc");
    Arc::new(BusCodec::load(&path, &skid_bindings()).expect("skid codec"))
}

/// Half the encoding step of each signal in `config/skid.dbc`, plus rounding slack.
fn sensor_tol(s: SensorId) -> f64 {
    let step = match s {
        SensorId::PSuction | SensorId::PDischarge => 1.0,
        SensorId::ShaftSpeed => 0.05,
        SensorId::OrificeDp => 0.5,
        SensorId::TSuction => 0.01,
        SensorId::RecycleValvePosition | SensorId::ThrottlePosition => 1e-4,
        SensorId::ThrustPosition => 1e-8,
        SensorId::DriveTorque => 0.5,
        SensorId::EsdInput => 1.0, // not in skid.dbc
    };
    step * 0.5 + 1e-12
}

fn actuator_tol(a: ActuatorId) -> f64 {
    let step = match a {
        ActuatorId::DriveTorque => 0.5,
        ActuatorId::RecycleValve | ActuatorId::Throttle | ActuatorId::CloseCoupledValve => 1e-4,
        ActuatorId::TipClearance => 1e-8,
    };
    step * 0.5 + 1e-12
}

fn snapshot() -> SensorSnapshot {
    let mut s = SensorSnapshot::default();
    s.set(SensorId::PSuction, 101_325.4);
    s.set(SensorId::PDischarge, 350_000.0);
    s.set(SensorId::ShaftSpeed, 1234.57);
    s.set(SensorId::OrificeDp, -1234.3);
    s.set(SensorId::TSuction, 300.153);
    s.set(SensorId::RecycleValvePosition, 0.34567);
    s.set(SensorId::ThrottlePosition, 0.75);
    s.set(SensorId::ThrustPosition, 3.2e-5);
    s.set(SensorId::DriveTorque, 987.5);
    s
}

fn commands() -> ActuatorCommands {
    let mut c = ActuatorCommands::default();
    c.set(ActuatorId::DriveTorque, -1500.2);
    c.set(ActuatorId::RecycleValve, 0.4242);
    c.set(ActuatorId::CloseCoupledValve, 0.05);
    c.set(ActuatorId::Throttle, 0.8);
    c.set(ActuatorId::TipClearance, -2.5e-5);
    c
}

fn outputs(cycle: u64) -> Outputs {
    Outputs {
        commands: commands(),
        mode: Mode::Auto,
        law: 3,
        faults: 0x0000_0112,
        cycle,
        t_ns: 1,
    }
}

fn messages(c: &BusCodec, sensors: bool) -> Vec<MessageIndex> {
    if sensors {
        c.frames.sensor_messages().collect()
    } else {
        c.frames.actuator_messages().collect()
    }
}

fn refresh() -> Duration {
    Duration::from_millis(10)
}

/// (id, payload) of a data frame.
fn parts(f: &CanDataFrame) -> (FrameId, Vec<u8>) {
    (FrameId::from(f.id()), f.data().to_vec())
}

struct Controller {
    rx: RxHandler,
    sensors: Arc<SensorBoard>,
    counters: Arc<CanCounters>,
}

fn controller(c: &Arc<BusCodec>) -> Controller {
    let sensors = Arc::new(SensorBoard::default());
    let counters = Arc::new(CanCounters::default());
    Controller {
        rx: RxHandler::controller(Arc::clone(c), Arc::clone(&sensors), Arc::clone(&counters)),
        sensors,
        counters,
    }
}

struct Plant {
    rx: RxHandler,
    commands: Arc<CommandBoard>,
    heartbeat: Arc<HeartbeatBoard>,
    counters: Arc<CanCounters>,
}

fn plant(c: &Arc<BusCodec>) -> Plant {
    let commands = Arc::new(CommandBoard::default());
    let heartbeat = Arc::new(HeartbeatBoard::default());
    let counters = Arc::new(CanCounters::default());
    Plant {
        rx: RxHandler::plant(
            Arc::clone(c),
            Arc::clone(&commands),
            Arc::clone(&heartbeat),
            Arc::clone(&counters),
        ),
        commands,
        heartbeat,
        counters,
    }
}

/// Sensor frames as the plant node sends them.
fn sensor_frames(enc: &mut FrameEncoder, s: &SensorSnapshot) -> Vec<CanDataFrame> {
    (0..enc.len()).filter_map(|i| enc.encode(i, s, 0)).collect()
}

#[test]
fn controller_rx_publishes_sensors_within_resolution() {
    let c = codec();
    let mut ctl = controller(&c);
    let mut enc = FrameEncoder::new(&c.frames, &messages(&c, true), false, refresh()).expect("enc");
    let snap = snapshot();
    for (k, f) in sensor_frames(&mut enc, &snap).iter().enumerate() {
        let (id, data) = parts(f);
        assert_eq!(
            ctl.rx.handle_data(id, &data, 1_000 + k as u64),
            RxOutcome::Published
        );
    }
    for s in SensorId::ALL.into_iter().filter(|s| !s.is_contact()) {
        let (v, t) = ctl.sensors.get(s);
        assert!(
            (v - snap.get(s)).abs() <= sensor_tol(s),
            "{}: sent {} got {v}",
            s.name(),
            snap.get(s)
        );
        assert!((1_000..1_004).contains(&t), "{}: stamp {t}", s.name());
    }
    let n = ctl.counters.snapshot();
    assert_eq!(n.rx_published, 4);
    assert_eq!(
        n,
        CanCountersSnapshot {
            rx_published: 4,
            ..Default::default()
        }
    );
}

#[test]
fn the_cycle_trigger_fires_once_the_inputs_of_a_cycle_are_published() {
    // the default trigger on skid.dbc: PLANT_Pressures and PLANT_SpeedFlowTemp; the control
    // thread woken by the fire must find both messages' values on the board
    let c = codec();
    let sensors = Arc::new(SensorBoard::default());
    let counters = Arc::new(CanCounters::default());
    let trigger = Arc::new(CycleTrigger::new());
    let plan = c
        .trigger_plan(&CycleTriggerSpec::Inputs)
        .expect("resolves")
        .expect("plan");
    let mut rx = RxHandler::controller(Arc::clone(&c), Arc::clone(&sensors), counters)
        .with_trigger(Arc::clone(&trigger), &plan);
    assert!(trigger.is_armed());
    let mut enc = FrameEncoder::new(&c.frames, &messages(&c, true), false, refresh()).expect("enc");
    let name = |f: &CanDataFrame| {
        let (id, _) = parts(f);
        let m = c.frames.message_for_id(id).expect("known");
        c.frames.message_name(m).expect("named").to_string()
    };
    // the first sets in DBC order: pressures, speed, positions (every 2 ms), drive (10 ms).
    // No fire until every sensor message arrived once: the first cycle must find the measured
    // valve position to take over from
    let mut fires = Vec::new();
    for (batch, t0) in [(0u64, 1_000u64), (1, 2_000), (2, 3_000)] {
        // encoded 1 ms apart, each message at its DBC cycle time
        let snap = snapshot();
        let frames: Vec<_> = (0..enc.len())
            .filter_map(|i| enc.encode(i, &snap, batch * 1_000_000))
            .collect();
        assert_eq!(frames.len(), [4, 2, 3][batch as usize], "batch {batch}");
        for (k, f) in frames.iter().enumerate() {
            let (id, data) = parts(f);
            let before = trigger.count();
            rx.handle_data(id, &data, t0 + k as u64);
            if trigger.count() != before {
                fires.push((name(f), trigger.last_fire_ns()));
            }
        }
    }
    assert_eq!(
        fires,
        [
            ("PLANT_SpeedFlowTemp".to_string(), 2_001),
            ("PLANT_SpeedFlowTemp".to_string(), 3_001)
        ]
    );
    // all messages again (the encoder's slow messages are due at 10 ms)
    let mut enc = FrameEncoder::new(&c.frames, &messages(&c, true), false, refresh()).expect("enc");
    let frames = sensor_frames(&mut enc, &snapshot());
    // send in reverse DBC order: positions and drive torque do not count, the set completes
    // with the pressures, whichever comes last
    let mut fired_at = None;
    for (k, f) in frames.iter().enumerate().rev() {
        let (id, data) = parts(f);
        let before = trigger.count();
        let _ = rx.handle_data(id, &data, 5_000 + k as u64);
        if trigger.count() != before {
            assert!(fired_at.is_none(), "fired twice on one set");
            fired_at = Some((name(f), trigger.last_fire_ns()));
            // everything the cycle needs is already on the board
            for s in [
                SensorId::PSuction,
                SensorId::PDischarge,
                SensorId::ShaftSpeed,
            ] {
                assert!(
                    sensors.get(s).0.is_finite(),
                    "{} not published yet",
                    s.name()
                );
            }
        }
    }
    assert_eq!(fired_at, Some(("PLANT_Pressures".to_string(), 5_000)));
    // a repeated alive counter (stuck sender) is dropped and does not fire
    let (id, data) = parts(&frames[1]);
    let before = trigger.count();
    assert_eq!(
        rx.handle_data(id, &data, 6_000),
        RxOutcome::Rejected(RxReject::AliveRepeated)
    );
    let (id, data) = parts(&frames[0]);
    assert_eq!(
        rx.handle_data(id, &data, 6_001),
        RxOutcome::Rejected(RxReject::AliveRepeated)
    );
    assert_eq!(trigger.count(), before);
}

#[test]
fn malformed_and_unknown_frames_are_counted_not_published() {
    let c = codec();
    let mut ctl = controller(&c);
    let mut enc = FrameEncoder::new(&c.frames, &messages(&c, true), false, refresh()).expect("enc");
    let good = sensor_frames(&mut enc, &snapshot());
    let (id, data) = parts(&good[0]);

    let cases: Vec<(FrameId, Vec<u8>, RxReject)> = vec![
        (FrameId::Standard(0x555), data.clone(), RxReject::UnknownId),
        (FrameId::Extended(0x100), data.clone(), RxReject::UnknownId),
        (id, data[..5].to_vec(), RxReject::WrongDlc),
        (id, Vec::new(), RxReject::WrongDlc),
        (
            id,
            {
                let mut d = data.clone();
                d[0] ^= 0x40;
                d
            },
            RxReject::BadCrc,
        ),
        (
            id,
            {
                let mut d = data.clone();
                d[7] ^= 0x01;
                d
            },
            RxReject::BadCrc,
        ),
    ];
    for (id, d, why) in &cases {
        assert_eq!(
            ctl.rx.handle_data(*id, d, 5),
            RxOutcome::Rejected(*why),
            "{id} {d:02X?}"
        );
    }
    for s in SensorId::ALL.into_iter().filter(|s| !s.is_contact()) {
        assert_eq!(
            ctl.sensors.get(s).1,
            0,
            "{} must not be published",
            s.name()
        );
    }
    let n = ctl.counters.snapshot();
    assert_eq!((n.unknown_id, n.wrong_dlc, n.bad_crc), (2, 2, 2));
    assert_eq!(n.rx_published, 0);
    // The good frame still goes through afterwards.
    assert_eq!(ctl.rx.handle_data(id, &data, 9), RxOutcome::Published);
}

#[test]
fn repeated_alive_counter_is_not_published_skipped_is() {
    let c = codec();
    let mut ctl = controller(&c);
    let msgs = messages(&c, true);
    let mut enc = FrameEncoder::new(&c.frames, &msgs, false, refresh()).expect("enc");
    let mut snap = snapshot();
    // Frames of PLANT_Pressures (message 0 of the encoder) with counters 0, 1, 2, ...
    let mut frames = Vec::new();
    for k in 0..6 {
        snap.set(SensorId::PSuction, 100_000.0 + f64::from(k));
        // one frame per 1 ms cycle time of PLANT_Pressures
        frames.push(enc.encode(0, &snap, k as u64 * 1_000_000).expect("frame"));
    }
    let feed = |ctl: &mut Controller, f: &CanDataFrame, t: u64| {
        let (id, d) = parts(f);
        ctl.rx.handle_data(id, &d, t)
    };
    assert_eq!(feed(&mut ctl, &frames[0], 10), RxOutcome::Published);
    assert_eq!(feed(&mut ctl, &frames[1], 11), RxOutcome::Published);
    // Stuck sender: same frame again → dropped, the value keeps its old stamp.
    assert_eq!(
        feed(&mut ctl, &frames[1], 12),
        RxOutcome::Rejected(RxReject::AliveRepeated)
    );
    assert_eq!(ctl.sensors.get(SensorId::PSuction), (100_001.0, 11));
    // Frames 2 and 3 lost: frame 4 is published, two frames counted lost.
    assert_eq!(feed(&mut ctl, &frames[4], 13), RxOutcome::Published);
    assert_eq!(ctl.sensors.get(SensorId::PSuction), (100_004.0, 13));
    assert_eq!(feed(&mut ctl, &frames[5], 14), RxOutcome::Published);
    let n = ctl.counters.snapshot();
    assert_eq!(
        (n.alive_repeated, n.alive_skipped, n.frames_lost),
        (1, 1, 2)
    );
    assert_eq!(n.rx_published, 4);
    // After a reconnect the next counter is a fresh start, whatever its value.
    ctl.rx.reset_alive();
    assert_eq!(feed(&mut ctl, &frames[2], 15), RxOutcome::Published);
    assert_eq!(ctl.counters.snapshot().alive_skipped, 1);
}

const MS: u64 = 1_000_000;

/// Hand sensor frame `f` to the controller's receive side at `t_ns` (it must be published)
/// and read the suction pressure's sender clock, s (NaN: none).
fn sender_clock_after(ctl: &mut Controller, f: &CanDataFrame, t_ns: u64) -> f64 {
    let (id, d) = parts(f);
    assert_eq!(ctl.rx.handle_data(id, &d, t_ns), RxOutcome::Published);
    ctl.sensors.raw(t_ns).sample_clock_s[SensorId::PSuction.index()]
}

/// The steps between consecutive sender clocks are `want`, ms.
fn assert_clock_steps_ms(clocks: &[f64], want: &[f64]) {
    let steps: Vec<f64> = clocks.windows(2).map(|w| (w[1] - w[0]) * 1e3).collect();
    assert_eq!(steps.len(), want.len(), "steps {steps:?} ms");
    for (got, want) in steps.iter().zip(want) {
        assert!((got - want).abs() < 1e-6, "steps {steps:?} ms");
    }
}

#[test]
fn the_samples_are_timed_on_the_senders_clock_from_the_alive_counter() {
    // PLANT_Pressures every 1 ms (GenMsgCycleTime), arriving late, in a batch, and after two
    // lost frames: the board's sender clock advances by the counter's steps × 1 ms
    let c = codec();
    let mut ctl = controller(&c);
    let msgs = messages(&c, true);
    let mut enc = FrameEncoder::new(&c.frames, &msgs, false, refresh()).expect("enc");
    let snap = snapshot();
    let frames: Vec<_> = (0..6u64)
        .map(|k| enc.encode(0, &snap, k * MS).expect("frame"))
        .collect();
    let arrivals = [
        (0, 5 * MS),
        (1, 8 * MS + 400_000), // 3.4 ms after the last: the receiver (or the sender's host) stood
        (2, 8 * MS + 410_000), // 10 µs later: a batch
        (5, 11 * MS + 500_000), // two frames lost
    ];
    let clocks: Vec<f64> = arrivals
        .into_iter()
        .map(|(k, t)| {
            let clock = sender_clock_after(&mut ctl, &frames[k], t);
            assert_eq!(ctl.sensors.raw(t).age_s[SensorId::PSuction.index()], 0.0);
            clock
        })
        .collect();
    assert_clock_steps_ms(&clocks, &[1.0, 1.0, 3.0]);
    // a reading from a source without a counter carries no sender clock
    ctl.sensors.publish(SensorId::PSuction, 1e5, 20 * MS);
    assert!(ctl.sensors.raw(20 * MS).sample_clock_s[SensorId::PSuction.index()].is_nan());
}

#[test]
fn a_sender_slower_than_its_dbc_cycle_time_loses_its_clock_and_is_counted() {
    // PLANT_Pressures is declared at 1 ms; this sender sends every 2 ms, +1 per frame: after a
    // second of arrivals its counter's time is half the arrivals', the clock is withdrawn
    // (samples timed by arrival), the counter says so once
    let c = codec();
    let mut ctl = controller(&c);
    let msgs = messages(&c, true);
    let mut enc = FrameEncoder::new(&c.frames, &msgs, false, refresh()).expect("enc");
    let snap = snapshot();
    let mut withdrawn_at = None;
    for k in 0..700u64 {
        let t = 2 * k * MS;
        let f = enc.encode(0, &snap, t).expect("frame");
        let clock = sender_clock_after(&mut ctl, &f, t);
        if clock.is_nan() && withdrawn_at.is_none() {
            withdrawn_at = Some(k);
        }
        assert_eq!(
            clock.is_nan(),
            withdrawn_at.is_some(),
            "withdrawn for good at {k}"
        );
    }
    assert_eq!(withdrawn_at, Some(500), "after one second of arrivals");
    assert_eq!(ctl.counters.snapshot().sender_clock_distrusted, 1);
}

#[test]
fn a_sender_counting_sample_periods_keeps_the_receivers_clock_on_its_own() {
    // the simulated plant encodes on its step time; a step whose frame it could not send (its
    // task late) counts in the alive counter, so the receiver's sender clock still advances
    // by every plant period, however the frames arrive
    let c = codec();
    let mut ctl = controller(&c);
    let msgs = messages(&c, true);
    let mut enc = FrameEncoder::new(&c.frames, &msgs, false, refresh())
        .expect("enc")
        .counting_sample_periods();
    let snap = snapshot();
    // plant steps at 0, 1, 3 (the step at 2 unsent) and 4 ms; all arriving 10 µs apart
    let clocks: Vec<f64> = [0u64, 1, 3, 4]
        .into_iter()
        .enumerate()
        .map(|(k, plant_ms)| {
            let f = enc.encode(0, &snap, plant_ms * MS).expect("frame");
            sender_clock_after(&mut ctl, &f, 50 * MS + k as u64 * 10_000)
        })
        .collect();
    assert_clock_steps_ms(&clocks, &[1.0, 2.0, 1.0]);
    assert_eq!(
        ctl.counters.snapshot().frames_lost,
        1,
        "the unsent step counts as lost"
    );
    // a sender counting frames (the default) would have said 1 ms for the 2-ms step
    let mut plain = FrameEncoder::new(&c.frames, &msgs, false, refresh()).expect("enc");
    let a = plain.encode(0, &snap, 0).expect("frame");
    let b = plain.encode(0, &snap, 2 * MS).expect("frame");
    assert_eq!(
        (parts(&b).1[6] & 0x0F).wrapping_sub(parts(&a).1[6] & 0x0F) & 0x0F,
        1,
        "PLANT_Pressures' counter (byte 6, low nibble) steps by one frame"
    );
}

#[test]
fn controller_ignores_frames_it_does_not_consume() {
    let c = codec();
    let mut ctl = controller(&c);
    let mut cmd =
        FrameEncoder::new(&c.frames, &messages(&c, false), false, refresh()).expect("enc");
    let f = cmd.encode(0, &commands(), 0).expect("frame");
    let (id, d) = parts(&f);
    assert_eq!(
        ctl.rx.handle_data(id, &d, 1),
        RxOutcome::Rejected(RxReject::Foreign)
    );
    // Another controller's heartbeat, too.
    let mut hb = HeartbeatTx::new(&c.heartbeat).expect("hb");
    let f = hb.next_frame(Some(&outputs(1))).expect("heartbeat");
    let (id, d) = parts(&f);
    assert_eq!(
        ctl.rx.handle_data(id, &d, 1),
        RxOutcome::Rejected(RxReject::Foreign)
    );
    assert_eq!(ctl.counters.snapshot().foreign, 2);
}

#[test]
fn tx_from_output_board_round_trips_to_plant_command_board() {
    let c = codec();
    let board = OutputBoard::default();
    board.publish(&outputs(7));
    let latest = board.latest().expect("published");
    let mut enc =
        FrameEncoder::new(&c.frames, &messages(&c, false), false, refresh()).expect("enc");
    assert_eq!(enc.len(), 2);
    let mut p = plant(&c);
    for i in 0..enc.len() {
        let f = enc.encode(i, &latest.commands, 0).expect("frame");
        let (id, d) = parts(&f);
        assert_eq!(d.len(), 8);
        assert_eq!(p.rx.handle_data(id, &d, 77), RxOutcome::Published);
    }
    for a in ActuatorId::ALL {
        let (v, t) = p.commands.get(a);
        assert!(
            (v - commands().get(a)).abs() <= actuator_tol(a),
            "{}: sent {} got {v}",
            a.name(),
            commands().get(a)
        );
        assert_eq!(t, 77);
    }

    // Heartbeat from the same outputs.
    let mut hb = HeartbeatTx::new(&c.heartbeat).expect("hb");
    let f = hb.next_frame(Some(&latest)).expect("heartbeat");
    let (id, d) = parts(&f);
    assert_eq!(id, FrameId::Standard(0x80));
    assert_eq!(p.rx.handle_data(id, &d, 88), RxOutcome::Published);
    assert_eq!(
        p.heartbeat.latest(),
        Some(HeartbeatSeen {
            mode: Mode::Auto,
            law: 3,
            alive: 0,
            faults: 0x112,
            t_ns: 88
        })
    );
    assert_eq!(p.counters.snapshot().rx_published, 3);
}

#[test]
fn nan_setpoint_is_sent_as_not_available_and_alive_counts_up() {
    let c = codec();
    let mut enc =
        FrameEncoder::new(&c.frames, &messages(&c, false), false, refresh()).expect("enc");
    let mut p = plant(&c);
    let mut cmd = commands();
    let f0 = enc.encode(0, &cmd, 0).expect("frame");
    cmd.set(ActuatorId::RecycleValve, f64::NAN); // not driven any more
    cmd.set(ActuatorId::DriveTorque, 10.0);
    let f1 = enc.encode(0, &cmd, 1_000_000).expect("frame");
    let (id, d0) = parts(&f0);
    let (_, d1) = parts(&f1);
    assert_eq!(d0[6] & 0x0F, 0);
    assert_eq!(d1[6] & 0x0F, 1, "alive counter +1 per frame");
    assert_eq!(p.rx.handle_data(id, &d0, 1), RxOutcome::Published);
    let (v, _) = p.commands.get(ActuatorId::RecycleValve);
    assert!((v - 0.4242).abs() <= actuator_tol(ActuatorId::RecycleValve));
    assert_eq!(p.rx.handle_data(id, &d1, 2), RxOutcome::Published);
    // RecycleValveCmd (14 bits from bit 18) went out all ones, and arrives as "not driven"
    let raw = (u32::from_le_bytes([d1[2], d1[3], d1[4], 0]) >> 2) & 0x3FFF;
    assert_eq!(raw, 0x3FFF, "{d1:02x?}");
    let (v, t) = p.commands.get(ActuatorId::RecycleValve);
    assert!(v.is_nan(), "{v}");
    assert_eq!(t, 2);
    assert_eq!(p.commands.get(ActuatorId::DriveTorque).0, 10.0);
}

/// Every message at its DBC cycle time (`GenMsgCycleTime`) whatever the wakeup rate: over
/// 200 ms of 1 kHz wakeups jittering by ±0.3 ms, the 1 ms messages go out 200 times, the 2 ms
/// positions 100 times and the 10 ms drive report 20 times; two frames of one message are
/// never closer than half its cycle time (0.4 ms for the 1 ms messages: the jitter itself).
#[test]
fn each_message_keeps_its_dbc_cycle_time() {
    let c = codec();
    let ms = 1_000_000u64;
    let msgs = messages(&c, true);
    let mut enc = FrameEncoder::new(&c.frames, &msgs, false, refresh()).expect("enc");
    let names: Vec<&str> = msgs
        .iter()
        .map(|&m| c.frames.message_name(m).expect("name"))
        .collect();
    assert_eq!(
        names,
        [
            "PLANT_Pressures",
            "PLANT_SpeedFlowTemp",
            "PLANT_Positions",
            "PLANT_Drive"
        ]
    );
    let periods: Vec<u64> = (0..enc.len())
        .map(|i| enc.period_ns(i).expect("period") / ms)
        .collect();
    assert_eq!(periods, [1, 1, 2, 10]);
    let snap = snapshot();
    let mut sent: Vec<Vec<u64>> = vec![Vec::new(); enc.len()];
    // deterministic jitter: 0, +0.3, -0.3, +0.1, -0.2 ms, repeating
    let jitter_us = [0i64, 300, -300, 100, -200];
    for k in 0..200u64 {
        let j = jitter_us[(k % 5) as usize];
        let now = (10 * ms + k * ms).saturating_add_signed(j * 1_000);
        for (i, times) in sent.iter_mut().enumerate() {
            let due = enc.is_due(i, now);
            match enc.encode(i, &snap, now) {
                Some(_) => {
                    assert!(due, "{}: sent while not due", names[i]);
                    times.push(now)
                }
                None => assert!(!due, "{}: due but not sent", names[i]),
            }
        }
    }
    let counts: Vec<usize> = sent.iter().map(Vec::len).collect();
    assert_eq!(counts, [200, 200, 100, 20], "frames per message in 200 ms");
    for (i, times) in sent.iter().enumerate() {
        let half = (periods[i] * ms / 2).min(400_000);
        for w in times.windows(2) {
            assert!(
                w[1] - w[0] >= half,
                "{}: frames {} ns apart",
                names[i],
                w[1] - w[0]
            );
        }
    }
    // A long gap (no wakeups for 50 ms) restarts the schedule instead of bursting.
    let now = 300 * ms;
    assert!(enc.encode(3, &snap, now).is_some());
    assert!(enc.encode(3, &snap, now + ms).is_none());
    assert!(enc.encode(3, &snap, now + 9 * ms).is_none());
    assert!(enc.encode(3, &snap, now + 10 * ms).is_some());
}

/// No frame before the first computed command: a message whose bound values are all NaN is
/// not sent at all (a device would otherwise see "not available" or a number nobody
/// computed); once one value is a number, the others go out as "not available" (J1939).
#[test]
fn nothing_is_sent_before_the_first_computed_command() {
    let c = codec();
    let ms = 1_000_000u64;
    let mut enc =
        FrameEncoder::new(&c.frames, &messages(&c, false), false, refresh()).expect("enc");
    let mut cmd = ActuatorCommands::default();
    for a in ActuatorId::ALL {
        cmd.set(a, f64::NAN);
    }
    for k in 0..5 {
        assert!(
            enc.encode(0, &cmd, k * ms).is_none(),
            "Cmd1 before a command"
        );
        assert!(
            enc.encode(1, &cmd, k * ms).is_none(),
            "Cmd2 before a command"
        );
    }
    cmd.set(ActuatorId::RecycleValve, 0.25);
    let f = enc.encode(0, &cmd, 5 * ms).expect("first computed command");
    let d = f.data();
    // RecycleValveCmd 0.25 = 2500 raw at bit 18; DriveTorqueCmd (18 bits signed) and
    // ThrottleCmd (14 bits at bit 32) "not available"
    let word = u64::from_le_bytes(d.try_into().expect("8 bytes"));
    assert_eq!((word >> 18) & 0x3FFF, 2500, "{d:02x?}");
    assert_eq!(word & 0x3_FFFF, 0x2_0000, "torque: sign bit only");
    assert_eq!((word >> 32) & 0x3FFF, 0x3FFF, "throttle: all ones");
    assert_eq!(d[6] & 0x0F, 0, "first frame has counter 0");
    assert!(
        enc.encode(1, &cmd, 5 * ms).is_none(),
        "Cmd2: still nothing computed"
    );
}

#[test]
fn on_change_only_skips_unchanged_and_refreshes() {
    let c = codec();
    let ms = 1_000_000u64;
    let mut enc = FrameEncoder::new(&c.frames, &messages(&c, false), true, refresh()).expect("enc");
    let mut cmd = commands();
    assert!(enc.encode(0, &cmd, 0).is_some(), "first frame always goes");
    assert!(
        enc.encode(0, &cmd, 3 * ms).is_none(),
        "unchanged within 10 ms"
    );
    cmd.set(ActuatorId::Throttle, 0.81);
    let f = enc.encode(0, &cmd, 4 * ms).expect("changed");
    assert_eq!(f.data()[6] & 0x0F, 1);
    // The other message (Cmd2) did not change either.
    assert!(enc.encode(1, &cmd, 4 * ms).is_some(), "first frame of Cmd2");
    assert!(enc.encode(1, &cmd, 5 * ms).is_none());
    // a value becoming NaN (not driven) is a change; staying NaN is not
    cmd.set(ActuatorId::TipClearance, f64::NAN);
    assert!(enc.encode(1, &cmd, 6 * ms).is_some());
    assert!(enc.encode(1, &cmd, 7 * ms).is_none());
    // Refresh after the period even if unchanged.
    let f = enc.encode(0, &cmd, 14 * ms).expect("refresh");
    assert_eq!(f.data()[6] & 0x0F, 2);
    assert!(enc.encode(7, &cmd, 0).is_none(), "out of range");
}

#[test]
fn heartbeat_withheld_without_fresh_outputs() {
    let c = codec();
    let mut hb = HeartbeatTx::new(&c.heartbeat).expect("hb");
    assert!(hb.next_frame(None).is_none(), "nothing published yet");
    let first = hb.next_frame(Some(&outputs(1))).expect("first");
    assert!(
        hb.next_frame(Some(&outputs(1))).is_none(),
        "control thread stuck at cycle 1"
    );
    let second = hb.next_frame(Some(&outputs(2))).expect("progress");
    let decode = |f: &CanDataFrame| c.heartbeat.decode(f.data()).expect("valid heartbeat");
    assert_eq!(decode(&first).1, Some(0));
    assert_eq!(decode(&second).1, Some(1), "counter +1 per frame sent");
    // (the mode travels as a `Mode`: an unknown code cannot reach the bus)
    let mut o = outputs(3);
    o.mode = Mode::FailSafe;
    let f = hb.next_frame(Some(&o)).expect("frame");
    assert_eq!(decode(&f).0.mode, Mode::FailSafe);
}

#[test]
fn plant_heartbeat_checks() {
    let c = codec();
    let mut p = plant(&c);
    let mut hb = HeartbeatTx::new(&c.heartbeat).expect("hb");
    let f = hb.next_frame(Some(&outputs(1))).expect("frame");
    let (id, d) = parts(&f);
    assert_eq!(p.rx.handle_data(id, &d, 5), RxOutcome::Published);
    // Repeated heartbeat: stuck controller, not published.
    assert_eq!(
        p.rx.handle_data(id, &d, 6),
        RxOutcome::Rejected(RxReject::AliveRepeated)
    );
    assert_eq!(p.heartbeat.latest().map(|h| h.t_ns), Some(5));
    // Mode 9 with a valid CRC: invalid value.
    let mut bad = [0x09u8, 1, 0, 0, 0, 0, 0, 0];
    bad[7] = frame_crc(id, &bad, 7);
    assert_eq!(
        p.rx.handle_data(id, &bad, 7),
        RxOutcome::Rejected(RxReject::InvalidValue)
    );
    // Bad CRC and short heartbeat.
    let mut corrupt = d.clone();
    corrupt[2] ^= 1;
    assert_eq!(
        p.rx.handle_data(id, &corrupt, 8),
        RxOutcome::Rejected(RxReject::BadCrc)
    );
    assert_eq!(
        p.rx.handle_data(id, &d[..3], 8),
        RxOutcome::Rejected(RxReject::WrongDlc)
    );
    // Sensor frames are foreign to the plant.
    let mut enc = FrameEncoder::new(&c.frames, &messages(&c, true), false, refresh()).expect("enc");
    let f = enc.encode(0, &snapshot(), 0).expect("frame");
    let (sid, sd) = parts(&f);
    assert_eq!(
        p.rx.handle_data(sid, &sd, 9),
        RxOutcome::Rejected(RxReject::Foreign)
    );
    let n = p.counters.snapshot();
    assert_eq!(
        (
            n.alive_repeated,
            n.invalid_value,
            n.bad_crc,
            n.wrong_dlc,
            n.foreign
        ),
        (1, 1, 1, 1, 1)
    );
    assert_eq!(p.commands.get(ActuatorId::Throttle).1, 0);
}

#[test]
fn remote_fd_and_error_frames() {
    let c = codec();
    let mut ctl = controller(&c);
    let id = StandardId::new(0x100).expect("id");
    let remote = CanRemoteFrame::new_remote(id, 8).expect("remote");
    assert_eq!(
        ctl.rx.handle_frame(&CanAnyFrame::Remote(remote), 1),
        RxOutcome::Rejected(RxReject::Remote)
    );
    let fd = CanFdFrame::new(id, &[0u8; 12]).expect("fd");
    assert_eq!(
        ctl.rx.handle_frame(&CanAnyFrame::Fd(fd), 1),
        RxOutcome::Rejected(RxReject::Fd)
    );
    let err = |cause: ErrorCause| CanAnyFrame::Error(CanErrorFrame::from(cause));
    let cases = [
        (err(ErrorCause::BusOff), BusCondition::BusOff),
        (
            err(ErrorCause::Controller(ControllerProblems::TX_PASSIVE)),
            BusCondition::Passive,
        ),
        (
            err(ErrorCause::Controller(
                ControllerProblems::RX_WARNING | ControllerProblems::TX_WARNING,
            )),
            BusCondition::Warning,
        ),
        (
            err(ErrorCause::Controller(ControllerProblems::ACTIVE)),
            BusCondition::Active,
        ),
        (err(ErrorCause::Restarted), BusCondition::Active),
        (err(ErrorCause::NoAck), BusCondition::Other),
        (
            err(ErrorCause::Counters { tx: 200, rx: 0 }),
            BusCondition::Other,
        ),
    ];
    for (frame, expected) in &cases {
        assert_eq!(
            ctl.rx.handle_frame(frame, 1),
            RxOutcome::Bus(*expected),
            "{frame:?}"
        );
    }
    // Bus-off together with a controller state: bus-off wins.
    let both = CanErrorFrame::from(socketcan::CanError::from_multiple(
        ErrorCause::Controller(ControllerProblems::TX_PASSIVE),
        [ErrorCause::BusOff],
    ));
    assert_eq!(classify_error_frame(&both), BusCondition::BusOff);
    // A data frame through handle_frame.
    let mut enc = FrameEncoder::new(&c.frames, &messages(&c, true), false, refresh()).expect("enc");
    let f = enc.encode(0, &snapshot(), 0).expect("frame");
    assert_eq!(
        ctl.rx.handle_frame(&CanAnyFrame::Normal(f), 2),
        RxOutcome::Published
    );
    let n = ctl.counters.snapshot();
    assert_eq!(
        (n.rx_frames, n.remote_frames, n.fd_frames, n.error_frames),
        (10, 1, 1, 7)
    );
    assert_eq!(n.rx_published, 1);
}

#[test]
fn every_decoded_value_is_published_and_never_infinite() {
    // Sweep raw bit patterns through the decoder: nothing panics, every frame with a good CRC
    // is published, and a value is a number or NaN ("not available"), never infinite.
    let c = codec();
    let mut ctl = controller(&c);
    let ids = [0x100u16, 0x101, 0x102];
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    for k in 0..3000u64 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let id = FrameId::Standard(ids[(k % 3) as usize]);
        let mut d = x.to_le_bytes();
        if k == 0 {
            // PLANT_Pressures with PSuction (Motorola, bytes 0..2) all ones: not available
            d[..3].copy_from_slice(&[0xFF; 3]);
        }
        d[7] = frame_crc(id, &d, 7);
        ctl.rx.reset_alive();
        assert_eq!(ctl.rx.handle_data(id, &d, k + 1), RxOutcome::Published);
        if k == 0 {
            assert!(ctl.sensors.get(SensorId::PSuction).0.is_nan());
        }
    }
    for s in SensorId::ALL.into_iter().filter(|s| !s.is_contact()) {
        let v = ctl.sensors.get(s).0;
        assert!(v.is_finite() || v.is_nan(), "{}: {v}", s.name());
    }
    assert!(ctl.sensors.get(SensorId::PSuction).0.is_finite());
}

#[test]
fn config_defaults_unknown_keys_and_validation() {
    let cfg: CanBusConfig =
        toml::from_str("interface = \"can0\"\ndbc = \"config/skid.dbc\"\n").expect("parse");
    assert_eq!(cfg, CanBusConfig::new("can0", "config/skid.dbc"));
    assert_eq!(
        (
            cfg.heartbeat_period_ms,
            cfg.heartbeat_timeout_ms,
            cfg.reconnect_backoff_initial_ms,
            cfg.reconnect_backoff_max_ms,
            cfg.tx_on_change_only
        ),
        (10, 100, 50, 2000, false)
    );
    assert!(cfg.validate().is_ok());
    let e = toml::from_str::<CanBusConfig>(
        "interface = \"can0\"\ndbc = \"x.dbc\"\nheartbeat_period = 5\n",
    )
    .expect_err("unknown key");
    assert!(e.to_string().contains("heartbeat_period"), "{e}");

    let bad = |f: fn(&mut CanBusConfig)| {
        let mut c = CanBusConfig::new("vcan0", "x.dbc");
        f(&mut c);
        c.validate().expect_err("invalid").to_string()
    };
    assert!(bad(|c| c.interface = String::new()).contains("interface"));
    assert!(bad(|c| c.interface = "a_very_long_ifname0".into()).contains("interface"));
    assert!(bad(|c| c.interface = "can 0".into()).contains("interface"));
    assert!(bad(|c| c.heartbeat_period_ms = 0).contains("heartbeat_period_ms"));
    assert!(bad(|c| c.heartbeat_timeout_ms = 10).contains("heartbeat_timeout_ms"));
    assert!(bad(|c| c.reconnect_backoff_initial_ms = 0).contains("initial"));
    assert!(bad(|c| c.reconnect_backoff_max_ms = 10).contains("reconnect_backoff_max_ms"));
}

#[test]
fn bus_state_text_and_event_mapping() {
    use crate::events::event::BusState as E;
    let down = DownCause::io(IoOp::Receive, &io::Error::from_raw_os_error(libc::ENETDOWN));
    assert_eq!(
        BusState::down(down).to_string(),
        format!(
            "down: receive failed: {}",
            io::Error::from_raw_os_error(libc::ENETDOWN)
        )
    );
    let r = BusState::Down {
        attempt: 2,
        backoff_ms: 100,
        cause: DownCause::BusOff,
    };
    assert_eq!(
        r.to_string(),
        "reconnect attempt 2 in 100 ms (down: bus-off)"
    );
    assert_eq!(
        BusState::down(DownCause::BusOff).to_event(),
        Some(E::BusOff)
    );
    assert_eq!(BusState::down(down).to_event(), Some(E::Down));
    assert_eq!(r.to_event(), None, "only the first attempt is an event");
    let r1 = BusState::Down {
        attempt: 1,
        backoff_ms: 50,
        cause: DownCause::BusOff,
    };
    assert_eq!(r1.to_event(), Some(E::Reconnecting));
    assert_eq!(
        BusState::Degraded(CanTrouble::ErrorPassive).to_event(),
        Some(E::Up)
    );
    assert_eq!(BusState::Stopped.to_event(), None);
    assert!(BusState::Degraded(CanTrouble::ErrorWarning).is_up() && !r.is_up());
}

#[test]
fn reporter_counts_error_passive_entries_once() {
    let (tx, rx) = watch::channel(BusState::Idle);
    let counters = CanCounters::default();
    let seen = Arc::new(std::sync::Mutex::new(Vec::new()));
    let log = Arc::clone(&seen);
    let hook: StateHook = Arc::new(move |s: &BusState| {
        log.lock().expect("log").push(*s);
    });
    let r = Reporter {
        interface: "vcan0",
        state: &tx,
        hook: Some(&hook),
        counters: &counters,
    };
    r.set(BusState::Up);
    r.set(BusState::Degraded(CanTrouble::ErrorPassive));
    r.set(BusState::Degraded(CanTrouble::ErrorPassive));
    r.set(BusState::Up);
    r.set(BusState::Degraded(CanTrouble::ErrorPassive));
    assert_eq!(*rx.borrow(), BusState::Degraded(CanTrouble::ErrorPassive));
    assert_eq!(counters.snapshot().error_passive, 2);
    // The hook sees every change once, in order.
    assert_eq!(
        *seen.lock().expect("log"),
        [
            BusState::Up,
            BusState::Degraded(CanTrouble::ErrorPassive),
            BusState::Up,
            BusState::Degraded(CanTrouble::ErrorPassive)
        ]
    );
}

fn fast_cfg(interface: &str) -> CanBusConfig {
    CanBusConfig {
        reconnect_backoff_initial_ms: 5,
        reconnect_backoff_max_ms: 40,
        ..CanBusConfig::new(interface, "config/skid.dbc")
    }
}

/// A hook recording every state change.
fn recorder() -> (StateHook, Arc<std::sync::Mutex<Vec<BusState>>>) {
    let seen = Arc::new(std::sync::Mutex::new(Vec::new()));
    let log = Arc::clone(&seen);
    let hook: StateHook = Arc::new(move |s: &BusState| log.lock().expect("log").push(*s));
    (hook, seen)
}

#[tokio::test(flavor = "current_thread")]
async fn missing_interface_backs_off_and_stops_on_shutdown() {
    // No interface "nocan7" (and maybe no CAN in the kernel at all): the controller task must
    // report the failure, retry with growing delays, never panic, and stop on shutdown.
    let c = codec();
    let (stop_tx, stop_rx) = watch::channel(false);
    let (handles, state_rx) = BusHandles::new(stop_rx);
    let (hook, seen) = recorder();
    let handles = handles.with_hook(hook);
    let counters = Arc::clone(&handles.counters);
    let boards = ControllerBoards {
        sensors: Arc::new(SensorBoard::default()),
        outputs: Arc::new(OutputBoard::default()),
        wake: Arc::new(Wakeup::new().expect("eventfd")),
        trigger: None,
    };
    let task = tokio::spawn(run_controller(
        fast_cfg("nocan7"),
        (*c).clone(),
        boards.clone(),
        handles,
    ));
    tokio::time::sleep(Duration::from_millis(300)).await;
    boards.wake.signal(); // nothing to send while down; must not matter
    let _ = stop_tx.send(true);
    let result = tokio::time::timeout(Duration::from_secs(2), task)
        .await
        .expect("stops promptly")
        .expect("no panic");
    assert!(result.is_ok(), "{result:?}");
    let n = counters.snapshot();
    // 5 + 10 + 20 + 40 + 40 + … ms: about 9 attempts in 300 ms, never a busy loop.
    assert!(
        (3..=20).contains(&n.open_failures),
        "open failures {}",
        n.open_failures
    );
    assert_eq!((n.reconnects, n.link_down, n.tx_frames), (0, 0, 0));
    assert_eq!(*state_rx.borrow(), BusState::Stopped);
    let seen = seen.lock().expect("log").clone();
    // Down once, then one Reconnecting per attempt with doubling delays, then Stopped.
    let enodev = |s: &BusState| {
        matches!(
            s,
            BusState::Down {
                cause: DownCause::Io {
                    op: IoOp::Open,
                    errno: Some(_),
                    ..
                },
                ..
            }
        )
    };
    assert!(enodev(&seen[0]), "{seen:?}");
    assert_eq!(
        seen.iter()
            .filter(|s| matches!(s, BusState::Down { attempt: 0, .. }))
            .count(),
        1
    );
    let attempts: Vec<(u32, u64)> = seen
        .iter()
        .filter_map(|s| match s {
            BusState::Down {
                attempt,
                backoff_ms,
                ..
            } if *attempt > 0 => Some((*attempt, *backoff_ms)),
            _ => None,
        })
        .collect();
    assert!(
        attempts.starts_with(&[(1, 5), (2, 10), (3, 20), (4, 40), (5, 40)]),
        "{attempts:?}"
    );
    assert_eq!(
        attempts.len() as u64,
        n.open_failures,
        "one attempt per failure"
    );
    assert_eq!(seen.last(), Some(&BusState::Stopped));
    assert!(!seen.iter().any(BusState::is_up), "{seen:?}");
}

#[tokio::test(flavor = "current_thread")]
async fn plant_task_stops_when_the_shutdown_sender_is_dropped() {
    let c = codec();
    let (stop_tx, stop_rx) = watch::channel(false);
    let (handles, state_rx) = BusHandles::new(stop_rx);
    let boards = PlantBoards {
        commands: Arc::new(CommandBoard::default()),
        heartbeat: Arc::new(HeartbeatBoard::default()),
        snapshots: Arc::new(SnapshotBoard::default()),
        wake: Arc::new(Wakeup::new().expect("eventfd")),
    };
    let task = tokio::spawn(run_plant(fast_cfg("nocan8"), (*c).clone(), boards, handles));
    tokio::time::sleep(Duration::from_millis(50)).await;
    drop(stop_tx);
    let result = tokio::time::timeout(Duration::from_secs(2), task)
        .await
        .expect("stops promptly")
        .expect("no panic");
    assert!(result.is_ok());
    assert_eq!(*state_rx.borrow(), BusState::Stopped);
}

#[tokio::test(flavor = "current_thread")]
async fn bad_config_is_an_error_not_a_retry_loop() {
    let c = codec();
    let (_stop_tx, stop_rx) = watch::channel(false);
    let (handles, _state) = BusHandles::new(stop_rx);
    let mut cfg = fast_cfg("vcan0");
    cfg.heartbeat_period_ms = 0;
    let boards = ControllerBoards {
        sensors: Arc::new(SensorBoard::default()),
        outputs: Arc::new(OutputBoard::default()),
        wake: Arc::new(Wakeup::new().expect("eventfd")),
        trigger: None,
    };
    let e = run_controller(cfg, (*c).clone(), boards, handles)
        .await
        .expect_err("invalid");
    assert!(
        matches!(
            e,
            CanBusError::Config {
                key: "heartbeat_period_ms",
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn codec_errors_are_reported() {
    let e = BusCodec::load(Path::new("/nonexistent/skid.dbc"), &skid_bindings())
        .expect_err("missing file");
    assert!(matches!(e, CanBusError::Dbc(_)), "{e}");
    let db = CanDatabase::from_file(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc"))
        .expect("dbc");
    let bindings = vec![crate::io::can::SignalBinding::sensor(
        SensorId::PSuction,
        "NoSuchMessage",
        "X",
    )];
    assert!(matches!(
        BusCodec::new(&db, &bindings),
        Err(CanBusError::Binding(_))
    ));
}

/// `[bus.can.frame_ids]`: the overridden messages go out under their new ids (29-bit here,
/// the CRC byte computed over the new id), the other end accepts them under the new ids only,
/// and the bus load counts the longer 29-bit frames.
#[test]
fn frame_id_override_changes_ids_on_both_ends_and_the_bus_load() {
    use crate::io::can::busload::BusLoad;
    use crate::io::can::dbc::FrameIdOverride;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc");
    let mut cfg = CanBusConfig::new("vcan0", &path);
    let plain = cfg.database(&path).expect("dbc");
    cfg.frame_ids
        .insert("CTRL_ActuatorCmd1".into(), FrameIdOverride::Id(0x18FF_1234));
    cfg.frame_ids.insert(
        "PLANT_Pressures".into(),
        FrameIdOverride::Explicit {
            id: 0x100,
            extended: Some(true),
        },
    );
    let db = cfg.database(&path).expect("overridden");
    assert_eq!(
        db.message("CTRL_ActuatorCmd1").map(|m| m.id()),
        Some(FrameId::Extended(0x18FF_1234))
    );
    assert_eq!(
        db.message("PLANT_Pressures").map(|m| m.id()),
        Some(FrameId::Extended(0x100))
    );
    let new = Arc::new(BusCodec::load_for(&cfg, &path, &skid_bindings()).expect("codec"));
    let old = codec();

    // controller → plant: CTRL_ActuatorCmd1 (actuator message 0)
    let frame = |c: &Arc<BusCodec>| {
        let mut e = FrameEncoder::new(&c.frames, &messages(c, false), false, refresh()).unwrap();
        parts(&e.encode(0, &commands(), 0).expect("frame"))
    };
    let (old_id, old_data) = frame(&old);
    let (new_id, new_data) = frame(&new);
    assert_eq!(old_id, FrameId::Standard(0xA0));
    assert_eq!(new_id, FrameId::Extended(0x18FF_1234));
    assert_eq!(old_data[..7], new_data[..7], "same signals");
    assert_eq!(
        new_data[7],
        frame_crc(new_id, &new_data, 7),
        "CRC over the new id"
    );
    assert_ne!(old_data[7], new_data[7]);
    let mut p = plant(&new);
    assert_eq!(p.rx.handle_data(new_id, &new_data, 1), RxOutcome::Published);
    assert_eq!(
        p.rx.handle_data(old_id, &old_data, 2),
        RxOutcome::Rejected(RxReject::UnknownId),
        "the DBC's id is no longer this message"
    );

    // plant → controller: PLANT_Pressures (sensor message 0), 29-bit id 0x100
    let mut e = FrameEncoder::new(&new.frames, &messages(&new, true), false, refresh()).unwrap();
    let (id, data) = parts(&sensor_frames(&mut e, &snapshot())[0]);
    assert_eq!(id, FrameId::Extended(0x100));
    let mut ctl = controller(&new);
    assert_eq!(ctl.rx.handle_data(id, &data, 1), RxOutcome::Published);
    assert!(
        (ctl.sensors.get(SensorId::PSuction).0 - snapshot().get(SensorId::PSuction)).abs() <= 1.0
    );
    assert_eq!(
        ctl.rx.handle_data(FrameId::Standard(0x100), &data, 2),
        RxOutcome::Rejected(RxReject::UnknownId)
    );

    // bus load: two 1-kHz messages now 160 instead of 135 bits per frame
    let before = BusLoad::of(&plain, 1_000_000).bits_per_s;
    let after = BusLoad::of(&db, 1_000_000).bits_per_s;
    assert_eq!(after - before, 2.0 * 25.0 * 1000.0);
}
