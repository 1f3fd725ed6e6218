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
#   benches/rss.sh [DURATION_S]    (default 20)
set -euo pipefail
cd "$(dirname "$0")/.."
dur=${1:-20}
nice -n 10 cargo build --release --quiet
bin=$PWD/target/release/antisurge
dir=$(mktemp -d)
pid=
trap '[[ -n $pid ]] && kill "$pid" 2>/dev/null; rm -rf "$dir"' EXIT
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
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
echo "antisurge run, default config, after ${dur} s:"
echo "  VmRSS now                  $(fmt "$rss")"
echo "  VmRSS highest (1-s samples) $(fmt "$peak_rss")"
echo "  VmHWM (kernel peak)        $(fmt "$hwm")"
echo "  VmLck (locked)             $(fmt "$lck")"
echo "  getrusage max RSS at exit  $(fmt "$ru")"
