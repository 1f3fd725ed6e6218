#!/usr/bin/env bash
# Flake check (issue 27): the end-to-end tests that start processes and sockets, run RUNS times
# (default 5) under `stress-ng --cpu 2` (both cores of the CI machine busy); any failure fails
# the block. Runs the test binaries that are already built (the first-hour block's `cargo test
# --release`): `cargo test --no-run` only names them, it does not rebuild. Prints each run's
# duration.
#
#   .ci/flake_check.sh [RUNS]        FLAKE_TESTS="binary:module ..." overrides the list
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-5}
# binary:module of the chosen e2e tests (processes, sockets, real-time scenarios); not the
# campaign or the Modbus rate study (minutes each), not modbus_link_outage (its one test is
# ignored). Kept small for the 45-min budget: with daemon_faults and hmi_field_lamps too one
# run took 113 s under stress-ng on the 2-core dev machine (2026-11-29), ~9.5 min for 5 runs,
# which pushed CI past 45 min; the default keeps the three files whose kill -9 and watchdog
# tests mixed clocks before (FLAKE_TESTS adds the others back).
read -r -a tests <<<"${FLAKE_TESTS:-daemon:daemon_e2e bus:modbus_foreign_e2e operator:operator_live}"

command -v stress-ng >/dev/null || { echo "flake check: stress-ng is not installed" >&2; exit 1; }
declare -A exe filters
while IFS=$'\t' read -r name path; do exe[$name]=$path; done < <(
    cargo test --release --no-run --message-format=json 2>/dev/null | python3 -c 'import json, sys
for l in sys.stdin:
    m = json.loads(l)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["target"]["kind"] == ["test"]:
        print(m["target"]["name"] + "\t" + m["executable"])')
for t in "${tests[@]}"; do
    bin=${t%%:*}
    [ -n "${exe[$bin]:-}" ] || { echo "flake check: no built test binary '$bin'" >&2; exit 1; }
    filters[$bin]="${filters[$bin]:-} ${t#*:}::"
done

stress-ng --cpu 2 --quiet &
stress_pid=$!
trap 'kill "$stress_pid" 2>/dev/null; wait "$stress_pid" 2>/dev/null || true' EXIT
sleep 1
kill -0 "$stress_pid" || { echo "flake check: stress-ng did not start" >&2; exit 1; }
failed=0
for run in $(seq 1 "$runs"); do
    t=$SECONDS
    for bin in "${!filters[@]}"; do
        # shellcheck disable=SC2086 # one filter per word
        if ! "${exe[$bin]}" ${filters[$bin]} >"target/flake-$bin-$run.log" 2>&1; then
            echo "flake check: run $run of $bin (${filters[$bin]# }) FAILED:"
            grep -E "^test .* FAILED$|^---- |panicked at" "target/flake-$bin-$run.log" | head -40
            failed=$((failed + 1))
        fi
        grep -E "^test result:" "target/flake-$bin-$run.log" | sed "s/^/  run $run $bin: /"
    done
    echo "(flake check run $run/$runs: $((SECONDS - t)) s)"
done
[ "$failed" = 0 ] || { echo "flake check: $failed failing binary runs of $((runs * ${#filters[@]})) under stress-ng --cpu 2" >&2; exit 1; }
echo "flake check: ${#tests[@]} test files x $runs runs under stress-ng --cpu 2: all passed"
