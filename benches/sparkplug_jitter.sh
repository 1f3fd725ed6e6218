#!/usr/bin/env bash
# Benchmark (not a test): the control loop's wake-up jitter with and without the Sparkplug B
# edge node, in one run of this script on one machine. Three daemons in turn, each with the
# embedded plant on the shipped config for RUN_S seconds (throttle closure, then held):
#   none    the node off
#   node    the node on, the broker up throughout
#   outage  the node on, the broker stopped for 10 s in the middle (store-and-forward)
# Prints the cycle statistics each daemon writes at exit (status.stats_file): cycles,
# overruns, wake-up jitter p50/p99/max. Needs Debian's mosquitto.
#
#   benches/sparkplug_jitter.sh [RUN_S]     (default 30)
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
bin=$root/target/release/antisurge
run_s=${1:-30}
[[ -x $bin ]] || cargo build --release
work=$(mktemp -d)
mosq_pid=""
cleanup() { [[ -n $mosq_pid ]] && kill "$mosq_pid" 2>/dev/null; wait 2>/dev/null || true; rm -rf "$work"; }
trap cleanup EXIT
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
printf 'listener %s 127.0.0.1\nallow_anonymous true\n' "$port" >"$work/mosquitto.conf"
start_broker() { mosquitto -c "$work/mosquitto.conf" >>"$work/mosquitto.log" 2>&1 & mosq_pid=$!; sleep 0.5; }
stop_broker() { kill "$mosq_pid" 2>/dev/null; wait "$mosq_pid" 2>/dev/null || true; mosq_pid=""; }

run() {  # $1: name, $2: sparkplug enabled (true/false), $3: outage (0/1)
    local d=$work/$1
    mkdir -p "$d"
    env ANTISURGE_SPARKPLUG__ENABLED="$2" ANTISURGE_SPARKPLUG__BROKER="127.0.0.1:$port" \
        ANTISURGE_SPARKPLUG__GROUP_ID=bench ANTISURGE_SPARKPLUG__EDGE_NODE_ID="$1" \
        ANTISURGE_STATUS__SOCKET="$d/status.sock" ANTISURGE_STATUS__STATE_DIR="$d/state" \
        ANTISURGE_STATUS__METRICS_LISTEN="" ANTISURGE_STATUS__HMI_LISTEN="" \
        ANTISURGE_STATUS__STATS_FILE="$d/stats.json" ANTISURGE_EVENT_LOG__PATH="$d/events.jsonl" \
        "$bin" run --config "$root/config/antisurge.toml" >"$d/daemon.log" 2>&1 &
    local pid=$!
    if [[ $3 == 1 ]]; then
        sleep $(( (run_s - 10) / 2 )); stop_broker; sleep 10; start_broker
        sleep $(( run_s - 10 - (run_s - 10) / 2 ))
    else
        sleep "$run_s"
    fi
    kill -TERM "$pid"; wait "$pid" || true
    echo "  $1: node log lines: $(grep -ci 'sparkplug' "$d/daemon.log" || true) (first: $(grep -i -m1 'sparkplug' "$d/daemon.log" | cut -c1-120))"
    python3 - "$1" "$d/stats.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[2]))
w = s["wake_jitter_us"]
print(f"{sys.argv[1]:>7}: {s['cycles']} cycles at {s['rate_hz']} Hz, overruns {s['overruns']}, "
      f"wake-up jitter p50 {w['p50_us']:.0f} / p99 {w['p99_us']:.0f} / max {w['max_us']:.0f} us, "
      f"compute p99 {s['compute_us']['p99_us']:.1f} us")
PY
}
start_broker
echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
run none false 0
run node true 0
run outage true 1
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
