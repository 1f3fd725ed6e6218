#!/usr/bin/env bash
# Real-time figures of README.md ("Real-time figures"), natively: `antisurge run` with the
# in-process plant at 1 kHz for 20 s, and cyclictest at the same priority in the same run.
# Needs root (SCHED_FIFO, mlockall) and rt-tests (cyclictest). Prints one JSON object.
#
#   benches/rt_figures.sh [PRIORITY]        (default 80)
set -euo pipefail
cd "$(dirname "$0")/.."
prio=${1:-80}
bin=target/release/antisurge
[[ -x $bin ]] || cargo build --release
command -v cyclictest >/dev/null || { echo "cyclictest missing: apt-get install rt-tests" >&2; exit 1; }
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
cat >"$dir/antisurge.toml" <<TOML
[plant]
file = "$PWD/config/plants/kvangardsnes2009_recycle.toml"
[control]
law = "recycle-pi"
[cycle]
rate_hz = 1000.0
priority = $prio
lock_memory = true
[event_log]
path = "$dir/events.jsonl"
[simulation]
scenario = "throttle-closure"
[status]
stats_file = "$dir/stats.json"
TOML
cyclictest -m -p "$prio" -i 1000 -D 20 -q -h 20000 >"$dir/cyclictest.txt" 2>&1 &
ct=$!
"$bin" run --config "$dir/antisurge.toml" --duration-s 20 --out "$dir/plant" >"$dir/run.log" 2>&1
wait "$ct"
python3 - "$dir" <<'PY'
import json, sys
from pathlib import Path
d = Path(sys.argv[1])
sys.path.insert(0, "hil/suite")
from cyclictest_hist import stats as cyclictest_stats
stats = json.loads((d / "stats.json").read_text())
print(json.dumps({
    "antisurge_wake_jitter_us": stats["wake_jitter_us"],
    "antisurge_compute_us": stats["compute_us"],
    "antisurge_input_age_us": stats["input_age_us"],
    "overruns": stats["overruns"], "cycles": stats["cycles"],
    "max_rss_kib": stats["max_rss_kib"],
    "cyclictest_us": cyclictest_stats((d / "cyclictest.txt").read_text()),
}, indent=1))
PY
