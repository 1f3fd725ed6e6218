#!/usr/bin/env bash
# Loop jitter with and without the operator surfaces polled (README "Live status, metrics and
# HMI": figures). Runs `antisurge run` (in-process plant, 1 kHz, throttle closure) twice for
# DURATION s: once unpolled, once with `antisurge status --json`, GET /metrics and the HMI's
# GET /api/status each polled at 10 Hz. Prints the wake-jitter p99 of both runs (µs) and the
# ratio. Real-time priority needs root (or an rtprio limit).
#
#   benches/live_poll_jitter.sh [DURATION_S]    (default 20)
set -euo pipefail
cd "$(dirname "$0")/.."
dur=${1:-20}
bin=$PWD/target/release/antisurge
[[ -x $bin ]] || cargo build --release
dir=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$dir"' EXIT
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
run() { # $1 = name, $2 = poll (0/1)
    local m h
    m=$(free_port); h=$(free_port)
    cat >"$dir/$1.toml" <<TOML
[plant]
file = "$PWD/config/plants/kvangardsnes2009_recycle.toml"
[control]
law = "recycle-pi"
[cycle]
rate_hz = 1000.0
priority = 80
lock_memory = true
[event_log]
path = "$dir/$1-events.jsonl"
[simulation]
scenario = "throttle-closure"
[status]
stats_file = "$dir/$1-stats.json"
socket = "$dir/$1.sock"
state_dir = "$dir/$1-state"
metrics_listen = "127.0.0.1:$m"
hmi_listen = "127.0.0.1:$h"
TOML
    "$bin" run --config "$dir/$1.toml" --duration-s "$dur" >"$dir/$1.log" 2>&1 &
    local pid=$!
    if [[ $2 == 1 ]]; then
        sleep 1
        while kill -0 "$pid" 2>/dev/null; do
            "$bin" status --json --socket "$dir/$1.sock" >/dev/null 2>&1 || true
            curl -s "http://127.0.0.1:$m/metrics" >/dev/null || true
            curl -s "http://127.0.0.1:$h/api/status" >/dev/null || true
            sleep 0.1
        done
    fi
    wait "$pid"
}
run unpolled 0
run polled 1
python3 - "$dir" <<'PY'
import json, sys
d = sys.argv[1]
a = json.load(open(f"{d}/unpolled-stats.json"))
b = json.load(open(f"{d}/polled-stats.json"))
pa, pb = a["wake_jitter_us"]["p99_us"], b["wake_jitter_us"]["p99_us"]
print(json.dumps({"unpolled_p99_us": pa, "polled_p99_us": pb, "ratio": round(pb / pa, 3),
                  "unpolled_max_us": a["wake_jitter_us"]["max_us"], "polled_max_us": b["wake_jitter_us"]["max_us"],
                  "compute_p99_us": [a["compute_us"]["p99_us"], b["compute_us"]["p99_us"]],
                  "cycles": [a["cycles"], b["cycles"]]}))
PY
