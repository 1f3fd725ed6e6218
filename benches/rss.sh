#!/usr/bin/env bash
# Resident memory of the controller with the default config (README "Performance"; issue 25,
# item 8: target < 30 MB). Builds the release binary, starts `antisurge run` on the shipped
# config/antisurge.toml (the embedded simulated Kvangardsnes plant, 1 kHz, locked memory if
# the limits allow it: the log line "control thread at … Hz" says), lets it run DURATION s,
# reads VmRSS and VmHWM (peak) from /proc/<pid>/status, stops it with SIGTERM and prints the
# figures in MiB and MB, with the daemon's own getrusage peak from its stats file.
#
# Only the files the run writes are moved to a temporary directory (event log, status socket,
# state, stats) and the metrics/HMI ports to free ones, through the config's environment
# layer, so the run neither touches ./out nor collides with another daemon; every setting
# that sizes memory is the shipped one. Nothing timing-related is asserted.
#
#   benches/rss.sh [DURATION_S] [BIN]    (default 20 s; BIN: another build, e.g. the .deb's
#                                         `cargo build --profile dist` → target/dist/antisurge)
#
# `sim` mode: peak resident memory (getrusage of the child) of `antisurge sim --out` on a
# scenario of SIM_S simulated seconds (default 3600: one hour, 720 001 trace rows at the
# default 5-ms trace period) on the default plant and law: throttle closure at 5 s, then
# held. The trace streams to trace.csv (issue 25); BIN measures another build (e.g. one from
# before the streaming, to compare), default the one this script builds.
#
#   benches/rss.sh sim [SIM_S] [BIN]
#
# `run-out` mode: peak resident memory (getrusage of the child) of `antisurge run --out DIR
# --duration-s RUN_S` (default 120) on the shipped config with a scenario of an hour (the
# same long hold as `sim` mode), so the in-process plant traces for the whole run: 200 rows a
# second stream to trace.csv (issue 25; before, the daemon kept them until exit, 52 kB a
# second). Compare two durations to see whether memory grows with the run; BIN as for `sim`.
#
#   benches/rss.sh run-out [RUN_S] [BIN]
set -euo pipefail
cd "$(dirname "$0")/.."
long_scenario() {
    cat >"$1" <<SCENARIO
name = "long-hold"
description = "throttle 60 % -> 20 % over 2 s at 5 s, then held (benches/rss.sh)"
duration_s = $2

[initial]
throttle = 0.6

[[event]]
at_s = 5.0
ramp = { signal = "throttle", to = 0.2, over_s = 2.0 }
SCENARIO
}
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
if [[ ${1:-} == run-out ]]; then
    run_s=${2:-120}
    bin=${3:-}
    if [[ -z $bin ]]; then
        nice -n 10 cargo build --release --quiet
        bin=$PWD/target/release/antisurge
    fi
    dir=$(mktemp -d)
    trap 'rm -rf "$dir"' EXIT
    long_scenario "$dir/long.toml" 3600
    ANTISURGE_SIMULATION__SCENARIO="$dir/long.toml" \
    ANTISURGE_EVENT_LOG__PATH="$dir/events.jsonl" \
    ANTISURGE_STATUS__SOCKET="$dir/status.sock" \
    ANTISURGE_STATUS__STATE_DIR="$dir/state" \
    ANTISURGE_STATUS__STATS_FILE="$dir/stats.json" \
    ANTISURGE_STATUS__METRICS_LISTEN="127.0.0.1:$(free_port)" \
    ANTISURGE_STATUS__HMI_LISTEN="127.0.0.1:$(free_port)" \
    python3 - "$bin" "$dir" "$run_s" <<'PY'
import os, resource, subprocess, sys
bin, d, run_s = sys.argv[1], sys.argv[2], sys.argv[3]
r = subprocess.run([bin, "run", "--config", "config/antisurge.toml", "--duration-s", run_s,
                    "--out", f"{d}/out"], capture_output=True, text=True)
if r.returncode != 0:
    sys.exit(f"rss.sh: antisurge run failed:\n{r.stdout}{r.stderr}")
kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
with open(f"{d}/out/trace.csv", "rb") as f:
    rows = sum(1 for _ in f) - 1
size = os.path.getsize(f"{d}/out/trace.csv")
line = next((l.split("INFO ")[-1] for l in (r.stdout + r.stderr).splitlines()
             if "trace rows written" in l), "")
print(f"antisurge run --out --duration-s {run_s} {bin}: {line}")
print(f"  trace.csv                  {rows} rows, {size / 2**20:.1f} MiB")
print(f"  max RSS (getrusage)        {kib:6d} KiB = {kib / 1024:5.1f} MiB = {kib * 1024 / 1e6:5.1f} MB")
PY
    exit 0
fi
if [[ ${1:-} == sim ]]; then
    sim_s=${2:-3600}
    bin=${3:-}
    if [[ -z $bin ]]; then
        nice -n 10 cargo build --release --quiet
        bin=$PWD/target/release/antisurge
    fi
    dir=$(mktemp -d)
    trap 'rm -rf "$dir"' EXIT
    long_scenario "$dir/long.toml" "$sim_s"
    python3 - "$bin" "$dir" <<'PY'
import os, resource, subprocess, sys
bin, d = sys.argv[1], sys.argv[2]
r = subprocess.run([bin, "sim", "--config-dir", "config", "--scenario", f"{d}/long.toml",
                    "--out", f"{d}/out"], capture_output=True, text=True)
if r.returncode != 0:
    sys.exit(f"rss.sh: antisurge sim failed:\n{r.stdout}{r.stderr}")
kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
with open(f"{d}/out/trace.csv", "rb") as f:
    rows = sum(1 for _ in f) - 1
size = os.path.getsize(f"{d}/out/trace.csv")
line = next((l.strip() for l in r.stdout.splitlines() if "simulated in" in l), "")
print(f"antisurge sim --out {bin}: {line}")
print(f"  trace.csv                  {rows} rows, {size / 2**20:.0f} MiB")
print(f"  max RSS (getrusage)        {kib:6d} KiB = {kib / 1024:5.1f} MiB = {kib * 1024 / 1e6:5.1f} MB")
PY
    exit 0
fi
dur=${1:-20}
bin=${2:-}
if [[ -z $bin ]]; then
    nice -n 10 cargo build --release --quiet
    bin=$PWD/target/release/antisurge
fi
dir=$(mktemp -d)
pid=
trap '[[ -n $pid ]] && kill "$pid" 2>/dev/null; rm -rf "$dir"' EXIT
ANTISURGE_EVENT_LOG__PATH="$dir/events.jsonl" \
ANTISURGE_STATUS__SOCKET="$dir/status.sock" \
ANTISURGE_STATUS__STATE_DIR="$dir/state" \
ANTISURGE_STATUS__STATS_FILE="$dir/stats.json" \
ANTISURGE_STATUS__METRICS_LISTEN="127.0.0.1:$(free_port)" \
ANTISURGE_STATUS__HMI_LISTEN="127.0.0.1:$(free_port)" \
    "$bin" run --config config/antisurge.toml >"$dir/run.log" 2>&1 &
pid=$!
kib() { awk -v k="$1" '$1 == k":" { print $2 }' "/proc/$pid/status"; }
peak_rss=0
for ((i = 0; i < dur; i++)); do
    sleep 1
    kill -0 "$pid" 2>/dev/null || { cat "$dir/run.log" >&2; echo "rss.sh: antisurge run exited early" >&2; exit 1; }
    r=$(kib VmRSS)
    ((r > peak_rss)) && peak_rss=$r
done
rss=$(kib VmRSS)
hwm=$(kib VmHWM)
lck=$(kib VmLck)
kill -TERM "$pid"
wait "$pid" || { cat "$dir/run.log" >&2; echo "rss.sh: antisurge run failed" >&2; exit 1; }
pid=
ru=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["max_rss_kib"])' "$dir/stats.json")
grep -m1 "control thread at" "$dir/run.log" | sed 's/^.*INFO //' || true
fmt() { awk -v k="$1" 'BEGIN { printf "%6d KiB = %5.1f MiB = %5.1f MB", k, k / 1024, k * 1024 / 1e6 }'; }
echo "antisurge run, default config, after ${dur} s ($bin):"
echo "  VmRSS now                  $(fmt "$rss")"
echo "  VmRSS highest (1-s samples) $(fmt "$peak_rss")"
echo "  VmHWM (kernel peak)        $(fmt "$hwm")"
echo "  VmLck (locked)             $(fmt "$lck")"
echo "  getrusage max RSS at exit  $(fmt "$ru")"
