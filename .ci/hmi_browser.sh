#!/usr/bin/env bash
# Web HMI in real headless Chromium (Debian package) with playwright-core from npm.
# Needs: target/release/antisurge; apt-get install chromium; node + npm.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
bin=$root/target/release/antisurge
work=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
mkdir -p out
( cd .ci/hmi && [ -d node_modules/playwright-core ] || npm install --silent --no-audit --no-fund playwright-core@1 )
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
cd "$work"
# the throttle closure from an operating point right of the control line (recycle valve
# 60 % open at start: the law closes it, rate-limited, while the throttle closes), then, with
# the operator's station in manual at 0 % (the browser puts it there at about 20 s), a
# throttle step that protection must answer with a recycle trip
cat >closure.toml <<TOML
name = "hmi-throttle-closure"
description = "Recycle valve 60 % at start; throttle 60 % -> 20 % over 2 s at t = 4 s; 20 % -> 3 % in 0.3 s at t = 34 s"
duration_s = 90.0
[initial]
throttle = 0.6
recycle_valve = 0.6
[[event]]
at_s = 4.0
ramp = { signal = "throttle", to = 0.2, over_s = 2.0 }
[[event]]
at_s = 34.0
ramp = { signal = "throttle", to = 0.03, over_s = 0.3 }
TOML
# issue 24: a machine described from vendor data only (its surge line, no speed-line map) as
# the controller knows it, the independent simulated skid in process; the operator token
printf 'hmi-browser-token\n' >token && chmod 0600 token
# the surge counter as kept across restarts: 7, so that the reset test has something to reset
mkdir -p state && printf '{"surge_count":7,"safety_on_count":0,"auto":true}\n' >state/state.json
ANTISURGE_MACHINE__FILE="$root/config/machines/vendor_example.toml" \
ANTISURGE_PLANT__FILE="$root/tests/plants/vendor_skid_recycle.toml" \
ANTISURGE_STATUS__OPERATOR_TOKEN_FILE="$work/token" \
ANTISURGE_STATUS__HMI_LISTEN="127.0.0.1:$port" ANTISURGE_STATUS__METRICS_LISTEN="" \
ANTISURGE_STATUS__SOCKET="$work/status.sock" ANTISURGE_STATUS__STATE_DIR="$work/state" \
ANTISURGE_EVENT_LOG__PATH="$work/events.jsonl" ANTISURGE_SIMULATION__SCENARIO="$work/closure.toml" \
    "$bin" run --config "$root/config/antisurge.toml" >daemon.log 2>&1 &
for _ in $(seq 50); do curl -sf "http://127.0.0.1:$port/api/status" >/dev/null && break; sleep 0.1; done
node "$root/.ci/hmi/browser_test.mjs" "http://127.0.0.1:$port/" "$bin" "$work/status.sock" "$root/out/hmi.png" "$work/events.jsonl" \
    || { tail -20 daemon.log; exit 1; }
