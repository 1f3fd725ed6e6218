#!/usr/bin/env python3
"""Check one HIL case: the plant node's summary.json and trace.csv, the controller's event log
and statistics, against an in-process `antisurge sim` of the same plant, scenario and law.

Usage: check.py CASE DIR BIN. Prints the figures and exits 1 on a failed check.

Tolerances (stated here, printed with every run):
- no surge cycle and no flow reversal in any case;
- trajectory match with the in-process simulation (cases without a fault): the minimum
  compressor flow within 2 % and the RMS difference of the compressor flow over the run within
  2 % of its mean. The HIL plant's clock starts at the controller's first heartbeat; CAN
  quantises the signals (1 Pa, 0.05 rad/s, 0.5 Pa Δp) and adds up to one 1-ms period of delay.
- output bump (recycle-valve cases): between consecutive 5-ms trace rows the recycle-valve
  command moves less than 1 % of its stroke, except for the step into the fail-safe state
  itself (valve to its safe opening); after a link bounce the torque command moves less than
  1 % of the drive rating (the controller takes over from the drive's own governor).
- drive-torque: torque within the rating; its mean over 10–19 s within 2 % of the rating of
  the in-process run's.
- plant_pause: the drive-torque case with the plant stopped (SIGSTOP) 8 times for about 4 ms
  during the closure: the same checks; the samples carry the sender's clock, so the pauses
  are not integrated by the controller.
"""
import csv
import json
import math
import subprocess
import sys
from pathlib import Path

case, d, binary = sys.argv[1], Path(sys.argv[2]), sys.argv[3]
fails = []


def check(ok, what):
    print(("  ok   " if ok else "  FAIL ") + what)
    if not ok:
        fails.append(what)


def trace(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return [{k: float(v) if v not in ("", "NaN", "nan") else math.nan for k, v in r.items()} for r in rows]


def events(path):
    out = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                pass
    return out


s = json.loads((d / "plant" / "summary.json").read_text())
tr = trace(d / "plant" / "trace.csv")
ev = events(d / "events.jsonl")
stats_path = d / "controller_stats.json"
stats = json.loads(stats_path.read_text()) if stats_path.exists() else {}
print(f"case {case}: plant {s['plant']}, scenario {s['scenario']}, law {s['law']}, "
      f"{s['duration_s']:.1f} s, surge cycles {s['surge_cycles']}, min flow {s['min_flow_kg_s']:.3f} kg/s, "
      f"field fail-safe entries {s.get('field_failsafe_entries')}")
if stats:
    w = stats["wake_jitter_us"]
    c = stats["compute_us"]
    print(f"  controller: {stats['cycles']} cycles at {stats['rate_hz']} Hz, wake-up jitter p50 {w['p50_us']:.0f} / "
          f"p99 {w['p99_us']:.0f} / max {w['max_us']:.0f} us, compute p99 {c['p99_us']:.1f} us, "
          f"overruns {stats['overruns']}, max RSS {stats['max_rss_kib'] / 1024:.1f} MiB")

check(s["surge_cycles"] == 0 and not s["flow_reversal"], "no surge cycle, no flow reversal")
if s["surge_cycles"] or s["flow_reversal"]:
    # where it began, for the next look: the first reversal and the flow and commands before it
    k = next((i for i, r in enumerate(tr) if r["m_kg_s"] < 0), None)
    if k is not None:
        print(f"  first flow reversal at t = {tr[k]['t_s']:.3f} s (plant clock); the 50 ms before it:")
        for r in tr[max(0, k - 10):k + 1]:
            print(f"    t {r['t_s']:.3f} s  flow {r['m_kg_s']:.3f} kg/s  speed {r['omega_rad_s']:.1f} rad/s  "
                  f"torque {r['drive_torque_nm']:.1f} N m  throttle {r['throttle_position']:.3f}")

# the in-process reference
ref_dir = d / "sim"
subprocess.run([binary, "sim", "--plant", s["plant"], "--scenario", s["scenario"], "--law", s["law"],
                "--out", str(ref_dir), "--no-plots", "--json"], check=True, stdout=subprocess.DEVNULL)
ref = json.loads((ref_dir / "summary.json").read_text())
rtr = trace(ref_dir / "trace.csv")


def interp(rows, t, key):
    # rows are on a 5-ms grid starting at 0
    if t <= rows[0]["t_s"]:
        return rows[0][key]
    dt = rows[1]["t_s"] - rows[0]["t_s"]
    i = min(int((t - rows[0]["t_s"]) / dt), len(rows) - 2)
    a, b = rows[i], rows[i + 1]
    f = (t - a["t_s"]) / (b["t_s"] - a["t_s"])
    return a[key] + f * (b[key] - a[key])


if case in ("recycle_pi", "drive_torque", "malformed", "plant_pause"):
    check(s.get("field_failsafe_entries") == 0, "field devices never lost the controller")
    dmin = abs(s["min_flow_kg_s"] - ref["min_flow_kg_s"]) / abs(ref["min_flow_kg_s"])
    check(dmin <= 0.02, f"min flow {s['min_flow_kg_s']:.3f} vs in-process {ref['min_flow_kg_s']:.3f} kg/s: {100 * dmin:.2f} % (≤ 2 %)")
    t_end = min(tr[-1]["t_s"], rtr[-1]["t_s"])
    diffs = [(r["m_kg_s"] - interp(rtr, r["t_s"], "m_kg_s")) for r in tr if r["t_s"] <= t_end]
    rms = math.sqrt(sum(x * x for x in diffs) / len(diffs))
    mean = sum(abs(r["m_kg_s"]) for r in rtr) / len(rtr)
    worst = max(abs(x) for x in diffs)
    check(rms <= 0.02 * mean, f"flow RMS difference {rms:.4f} kg/s = {100 * rms / mean:.2f} % of mean {mean:.3f} (≤ 2 %); largest {worst:.4f} kg/s")

if case == "foreign_dbc":
    # the foreign skid's units and resolution (1 mbar, 0.5 rpm, 10 Pa) at a 100 Hz loop: no
    # trajectory match with the 1 kHz in-process run, but no surge and a heartbeat the skid's
    # watchdog accepted throughout
    check(s.get("field_failsafe_entries") == 0, "the skid's watchdog never lost the 16-bit counter heartbeat")

if case == "kill9":
    check(s.get("field_failsafe_entries") == 1, "field fail-safe entered once after kill -9")
    check(tr[-1]["recycle_valve_position"] > 0.95, f"recycle valve failed open: ends at {tr[-1]['recycle_valve_position']:.3f}")
    cmd = [(r["t_s"], r["cmd_recycle_valve"]) for r in tr]
    t_fs = next(t for t, v in cmd if t > 1.0 and v >= 0.999)
    t_last = max(t for t, v in cmd if t < t_fs and v < 0.999)
    check(t_fs - t_last <= 0.100 + 0.010 + 0.005 + 0.002,
          f"fail-safe command {1000 * (t_fs - t_last):.0f} ms after the last controller command (timeout 100 ms + heartbeat period 10 ms + trace 5 ms)")

if case in ("link_bounce", "malformed", "recycle_pi"):
    # output bumps on the recycle valve: every step between 5-ms rows, except the move *into*
    # the fail-safe state (valve to its safe opening: a designed step); the return to control
    # must be smooth. (The drive torque of these cases only holds speed; link_bounce checks it
    # below. Under drive-torque the torque moves by design: that case checks its trajectory.)
    t_stop = tr[-1]["t_s"] - 0.3
    rows = [(a, b) for a, b in zip(tr, tr[1:]) if a["t_s"] > 0.5 and b["t_s"] < t_stop]
    into_fs = {b["t_s"] for a, b in rows
               if b["cmd_recycle_valve"] >= 0.999 and not a["cmd_recycle_valve"] >= 0.999}
    # the return from fail-safe takes over from the *measured* valve position (issue 10): the
    # command steps from the safe opening to where the valve is, which moves nothing; that
    # step is checked against the valve position (< 2 % of travel), every other one against
    # the previous command (< 1 %)
    out_of_fs = {b["t_s"] for a, b in rows
                 if a["cmd_recycle_valve"] >= 0.999 and b["cmd_recycle_valve"] < 0.999}
    steps_v = [(abs(b["cmd_recycle_valve"] - a["cmd_recycle_valve"]), b["t_s"]) for a, b in rows
               if b["t_s"] not in into_fs and b["t_s"] not in out_of_fs
               and not math.isnan(a["cmd_recycle_valve"]) and not math.isnan(b["cmd_recycle_valve"])]
    resume = [(abs(b["cmd_recycle_valve"] - b["recycle_valve_position"]), b["t_s"]) for a, b in rows
              if b["t_s"] in out_of_fs]
    worst_r = max(resume, default=(0.0, 0.0))
    check(worst_r[0] < 0.02, f"resume from fail-safe: command {100 * worst_r[0]:.3f} % from the measured valve position at t = {worst_r[1]:.3f} s (< 2 %)")
    worst_v = max(steps_v, default=(0.0, 0.0))
    if into_fs:
        print(f"  (fail-safe entered at t = {', '.join(f'{t:.3f}' for t in sorted(into_fs))} s: that step is the safe state, not a bump)")
    check(worst_v[0] < 0.01, f"largest recycle-valve command step {100 * worst_v[0]:.3f} % at t = {worst_v[1]:.3f} s (< 1 %)")
    if case == "link_bounce":
        rating = 3000.0
        steps_t = [(abs(b["cmd_drive_torque_nm"] - a["cmd_drive_torque_nm"]), b["t_s"]) for a, b in rows]
        worst_t = max(steps_t, default=(0.0, 0.0))
        check(worst_t[0] < 0.01 * rating, f"largest torque command step {worst_t[0]:.1f} N·m at t = {worst_t[1]:.3f} s (< 1 % of {rating:.0f}): the controller took over from the drive's own governor")

if case == "plant_pause":
    lines = (d / "action.log").read_text().splitlines() if (d / "action.log").exists() else []
    ms = [float(l.split()[-2]) for l in lines if l.startswith("pause ")]
    check(len(ms) == 8, f"the plant was stopped 8 times during the closure ({len(ms)} logged)")
    # beyond 8 periods the 4-bit alive counter cannot tell a stopped sender from lost frames:
    # the controller then takes the arrival gap, right for a real sender (the process went on),
    # wrong for a simulated one whose time stood still
    check(bool(ms) and max(ms) < 8.0, f"each stop shorter than 8 ms, the counter's half range: {ms}")

if case in ("drive_torque", "plant_pause"):
    # the torque trajectory: inside the rating, and after the closure at the same mean as the
    # in-process run (CAN quantises the pressures to 1 Pa, which the law's flow gain turns
    # into ±60 N·m of torque ripple, so the mean, not each sample, is compared)
    rating = 1000.0
    peak = max(abs(r["cmd_drive_torque_nm"]) for r in tr if not math.isnan(r["cmd_drive_torque_nm"]))
    check(peak <= rating + 0.5, f"torque command peak {peak:.1f} N·m within the rating {rating:.0f}")
    def mean_torque(rows):
        v = [r["cmd_drive_torque_nm"] for r in rows if 10.0 <= r["t_s"] <= 19.0 and not math.isnan(r["cmd_drive_torque_nm"])]
        return sum(v) / len(v)
    mh, ms = mean_torque(tr), mean_torque(rtr)
    check(abs(mh - ms) <= 0.02 * rating, f"mean torque 10–19 s {mh:.1f} vs in-process {ms:.1f} N·m (within 2 % of the rating)")

if case == "link_bounce":
    modes = [(e["ts"], e["to"]) for e in ev if e.get("event") == "mode_changed"]
    first_auto = next((i for i, (_, m) in enumerate(modes) if m == "auto"), len(modes))
    fs = [i for i, (_, m) in enumerate(modes) if m == "fail_safe" and i > first_auto]
    check(bool(fs), f"controller entered fail-safe when the link went down (mode changes: {[m for _, m in modes]})")
    check(bool(fs) and any(m == "auto" for _, m in modes[fs[0]:]), "controller resumed auto when the link came back")
    bus = [e for e in ev if e.get("event") == "bus_state"]
    check(len(bus) >= 2, f"bus state changes logged: {[e.get('state') for e in bus]}")

if case == "malformed":
    burst = (d / "action.log").read_text().strip() if (d / "action.log").exists() else "(no action.log)"
    print("  burst: " + burst.replace("\n", "; "))
    can = (stats.get("links") or {}).get("can") or {}
    for k in ("unknown_id", "wrong_dlc", "bad_crc"):
        check(can.get(k, 0) >= 300, f"{k} counted: {can.get(k)} (sent 300)")
    modes = [e["to"] for e in ev if e.get("event") == "mode_changed"]
    check(modes.count("fail_safe") <= 1, f"no fail-safe caused by the burst (mode changes: {modes})")

if case == "timing":
    # the real-time figures of the README: the drive-torque pair, with cyclictest at the same
    # priority and candump on the bus during the same run
    check(s["surge_cycles"] == 0, "drive-torque pair out of surge while measured")
    w, c = stats["wake_jitter_us"], stats["compute_us"]
    ct = (d / "cyclictest.txt").read_text() if (d / "cyclictest.txt").exists() else ""
    sys.path.insert(0, str(Path(__file__).parent))
    from cyclictest_hist import stats as cyclictest_stats
    cs = cyclictest_stats(ct)
    n = cs["samples"]
    m = [f"p50 {cs['p50']} / p99 {cs['p99']} / max {cs['max']} us over {n} wake-ups"] if n else []
    check(n > 10000, f"cyclictest at the loops' priority, same run: {m[0] if m else ct.strip()[-300:]}")
    lat = json.loads(subprocess.run([sys.executable, str(Path(__file__).with_name("latency.py")),
                                     str(d / "candump.log"), "1", "17"],
                                    capture_output=True, text=True).stdout or "{}")
    check(lat.get("frames", 0) > 10000, f"sensor-frame-to-actuator-frame latency on vcan0 over {lat.get('frames', 0)} frames: "
          f"p50 {lat.get('p50_us', float('nan')):.0f} / p99 {lat.get('p99_us', float('nan')):.0f} / max {lat.get('max_us', float('nan')):.0f} us")
    check(lat.get("dropped", 1) == 0, f"candump dropped no frame ({lat.get('dropped')})")
    # inputs drive the cycle (issue 9, item 11): the controller runs on the arrival of its
    # sensor frames, so a command follows its sample by the compute time and two bus hops, not
    # by the phase between two free-running clocks (0.1-0.9 ms before)
    check(lat.get("p99_us", 1e9) < 200.0, "latency p99 under 200 us (the cycle runs on its inputs)")
    by_input, by_deadline = stats.get("cycles_by_input", 0), stats.get("cycles_by_deadline", 0)
    check(by_input >= 0.95 * stats["cycles"],
          f"cycles on their inputs: {by_input} of {stats['cycles']} ({by_deadline} on the deadline: before the first frames and after the plant stopped)")
    figures = {"controller_wake_jitter_us": w, "controller_compute_us": c, "overruns": stats["overruns"],
               "cycles": stats["cycles"], "max_rss_kib": stats["max_rss_kib"], "cyclictest": m[0] if m else None,
               "frame_latency_us": lat, "cycle_trigger": stats.get("cycle_trigger"),
               "cycles_by_input": by_input, "cycles_by_deadline": by_deadline}
    (d / "timing.json").write_text(json.dumps(figures, indent=1))
    print(f"  figures in {d / 'timing.json'}")

if fails:
    print(f"case {case}: FAILED ({len(fails)} check(s))")
    sys.exit(1)
print(f"case {case}: passed")
