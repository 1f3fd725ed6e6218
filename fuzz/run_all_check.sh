#!/usr/bin/env bash
# Checks fuzz/run_all.sh's contract with CI without building anything: stand-in targets
# (FUZZ_BIN_DIR) that pass or fail the way libFuzzer does. A failing target must make
# run_all.sh exit 1 and print FAILED in its table; passing targets must give exit 0 and their
# execution counts. Run by .ci/run before the real campaign.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=$(mktemp -d)
trap 'rm -rf "$bin"' EXIT
cat >"$bin/can_frame_decode" <<'EOF'
#!/bin/sh
echo "stat::number_of_executed_units: 1234"
exit 0
EOF
cat >"$bin/modbus_request" <<'EOF'
#!/bin/sh
echo "==1== ERROR: libFuzzer: deadly signal"
echo "stat::number_of_executed_units: 99"
exit 77
EOF
chmod +x "$bin"/*
run() { FUZZ_SKIP_BUILD=1 FUZZ_BIN_DIR="$bin" FUZZ_TARGETS="$1" fuzz/run_all.sh 1 2>/dev/null; }

set +e
out=$(run "can_frame_decode")
rc=$?
set -e
[ "$rc" -eq 0 ] || { echo "run_all.sh: exit $rc for a passing target (want 0)"; exit 1; }
grep -Eq '^can_frame_decode +1234 +[0-9]+ ok$' <<<"$out" || { echo "no 'ok' row with 1234 executions:"; echo "$out"; exit 1; }

set +e
out=$(run "can_frame_decode modbus_request")
rc=$?
set -e
[ "$rc" -eq 1 ] || { echo "run_all.sh: exit $rc with a crashing target (want 1)"; exit 1; }
grep -Eq '^modbus_request +99 +[0-9]+ FAILED: exit 77' <<<"$out" || { echo "no FAILED row for the crash:"; echo "$out"; exit 1; }
grep -Eq '^can_frame_decode +1234 ' <<<"$out" || { echo "the passing target's row is missing:"; echo "$out"; exit 1; }
echo "run_all.sh: exit 0 when every target passes, 1 and a FAILED row on a crash"
