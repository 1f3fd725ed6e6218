#!/usr/bin/env bash
# Build every fuzz target and run each for SECONDS (default 60), FUZZ_PARALLEL at a time.
# Prints a table: target, executions, seconds, result. Exits 1 if any target crashed (or hit
# libFuzzer's timeout or memory limit), 0 otherwise; the crashing input is in
# fuzz/artifacts/<target>/ (turn it into a regression test in tests/fuzz_regressions.rs).
#
# Seed corpora are made from the repository's own files (config/, tests/good_configs,
# tests/bad_configs, DBCs, a written event log) into fuzz/corpus/<target>/ (git-ignored).
# Needs the nightly toolchain and cargo-fuzz: `rustup toolchain install nightly`,
# `cargo install cargo-fuzz`. Environment: FUZZ_PARALLEL (targets at once, default 1),
# FUZZ_JOBS (default 1), FUZZ_TARGETS (a subset),
# FUZZ_SANITIZER (default none: the code under test is safe Rust, and without ASan a target
# runs about twice as many executions; `address` for the unsafe paths), FUZZ_RUNS (stop each
# target after this many executions instead of SECONDS; SECONDS is then only a cap),
# FUZZ_SKIP_BUILD=1 (run the targets already built, e.g. for a second campaign in parallel: the
# build script rebuilds the crate after every commit), FUZZ_BIN_DIR (where the built targets
# are; default fuzz/target/<host>/release, where `cargo fuzz build` puts them).
#
# Input length (-max_len) suits each format: a DBC or TOML file of 16 KiB holds every construct
# of the grammar (the largest shipped file, config/skid.dbc, is 11.6 KiB; config/antisurge.toml
# 10 KiB), and longer inputs only repeat them while each execution costs more (can-dbc's pest
# parser runs at ~1 µs per byte instrumented). The event reader gets 72 KiB so that a line past
# its 64 KiB limit (MAX_READ_LINE_BYTES) is reachable; the binary targets get a little more than
# their largest frame (CAN FD: 1 + 64 bytes; Modbus TCP ADU: 260 bytes).
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-60}
san=${FUZZ_SANITIZER:-none}
root=$PWD
targets=${FUZZ_TARGETS:-"can_frame_decode dbc_parse modbus_register_codec modbus_request config_layers plant_file scenario_file signal_map event_reader"}

max_len() {
    case $1 in
    can_frame_decode | modbus_register_codec) echo 128 ;;
    modbus_request) echo 512 ;;
    event_reader) echo 73728 ;;
    *) echo 16384 ;;
    esac
}

seed() {
    local t=$1 d=fuzz/corpus/$1
    mkdir -p "$d"
    case $t in
    dbc_parse) cp config/skid.dbc tests/cantools/*.dbc "$d"/ 2>/dev/null || true ;;
    plant_file)
        for f in config/plants/*.toml; do
            # relative map paths made absolute so seeds load from the scratch directory
            sed "s#\"\.\./maps/#\"$root/config/maps/#" "$f" >"$d/$(basename "$f")"
        done ;;
    scenario_file) cp config/scenarios/*.toml "$d"/ ;;
    signal_map) cp config/signals*.toml "$d"/ ;;
    config_layers)
        for f in config/antisurge.toml tests/good_configs/*.toml tests/bad_configs/*.toml; do
            [ -f "$f" ] || continue
            sed -e "s#^file = \"plants/#file = \"$root/config/plants/#" \
                -e "s#^signal_map = \"#signal_map = \"$root/config/#" \
                -e "s#^dbc = \"#dbc = \"$root/config/#" "$f" >"$d/$(basename "$f")"
        done
        printf '[plant]\nfile = "%s/config/plants/kvangardsnes2009_recycle.toml"\n%%%%\nANTISURGE_CONTROL__LAW=recycle-pi\nANTISURGE_A__B__C__D__E=1\n' "$root" >"$d/env.toml" ;;
    event_reader)
        printf '%s\n' \
            '{"ts":"2024-05-01T12:34:56.123456Z","seq":42,"event":"started","version":"0.1.0","config_path":"/etc/antisurge/antisurge.toml","law":"recycle-pi"}' \
            '{"ts":"2024-05-01T12:34:57.000001Z","seq":43,"event":"surge_detected","surge_count_total":3,"frequency_hz":8.5,"min_flow_kg_s":-0.42,"flow_reversal":true}' \
            '{"ts":"2024-05-01T12:34:58Z","seq":45,"event":"stopped","reason":"SIGTERM"}' \
            '{"ts":"2024-05-01T12:3' >"$d/seed.jsonl"
        printf '1h30m\n' >"$d/since" ;;
    modbus_request)
        printf '\x00\x01\x00\x00\x00\x06\x01\x03\x00\x00\x00\x02' >"$d/read"
        printf '\x00\x01\x00\x00\x00\x0b\x01\x10\x00\x00\x00\x02\x04\x00\x01\x00\x02' >"$d/write"
        printf '\x00\x01\x00\x00\x00\x07\x01\x0f\x00\x00\x00\x10\x00' >"$d/issue12_item9" ;;
    *) : ;;
    esac
}

if [ -z "${FUZZ_SKIP_BUILD:-}" ]; then
    echo "== building fuzz targets (cargo +nightly fuzz build)" >&2
    (cd fuzz && cargo +nightly fuzz build -s "$san") >&2
fi
# what `cargo fuzz run` runs after its build: the binaries of the host triple
bin=${FUZZ_BIN_DIR:-$root/fuzz/target/$(rustc +nightly -vV | sed -n 's/^host: //p')/release}
printf '%-24s %14s %8s %s\n' target executions seconds result
rows=$(mktemp -d)
trap 'rm -rf "$rows"' EXIT

# one target: its row into $rows/<target>.row, "1" into $rows/<target>.failed on a finding
run_target() {
    local t=$1 log result rc execs took start
    log="$rows/$t.log"
    result=ok
    local par=()
    if [ "${FUZZ_JOBS:-1}" -gt 1 ]; then par=(-jobs="$FUZZ_JOBS" -workers="$FUZZ_JOBS"); fi
    if [ -n "${FUZZ_RUNS:-}" ]; then par+=(-runs="$FUZZ_RUNS"); fi
    start=$(date +%s)
    mkdir -p "fuzz/artifacts/$t"
    (cd fuzz && "$bin/$t" -artifact_prefix="artifacts/$t/" -max_total_time="$secs" \
        -max_len="$(max_len "$t")" -rss_limit_mb=2048 -print_final_stats=1 "${par[@]}" "corpus/$t") \
        >"$log" 2>&1 || {
        rc=$?
        result="FAILED: exit $rc (crash, leak, timeout or out-of-memory; input in fuzz/artifacts/$t)"
        # libFuzzer's -interrupted_exitcode: stopped by SIGINT, not a finding (still not a pass)
        [ "$rc" -ne 72 ] || result="INTERRUPTED (SIGINT): no finding, the run was cut short"
        echo 1 >"$rows/$t.failed"
        { echo "---- $t: the last 40 lines of its log"; tail -n 40 "$log"; } >&2
    }
    execs=$({ grep -h 'stat::number_of_executed_units' "$log" fuzz/fuzz-*.log 2>/dev/null || true; } |
        awk '{s += $2} END {print s + 0}')
    took=$(($(date +%s) - start))
    printf '%-24s %14s %8s %s\n' "$t" "$execs" "$took" "$result" >"$rows/$t.row"
    if [ "${FUZZ_JOBS:-1}" -gt 1 ]; then rm -f fuzz/fuzz-*.log; fi
}

# FUZZ_PARALLEL targets at a time (default 1), each single-threaded for its full SECONDS: on
# CI's 2 cores two at a time halve the wall time and give each target the same CPU it had alone.
# With FUZZ_JOBS > 1 (libFuzzer's own workers share fuzz/fuzz-*.log) targets run one at a time.
parallel=${FUZZ_PARALLEL:-1}
if [ "${FUZZ_JOBS:-1}" -gt 1 ]; then parallel=1; fi
running=0
for t in $targets; do
    seed "$t"
    run_target "$t" &
    running=$((running + 1))
    if [ "$running" -ge "$parallel" ]; then
        wait -n || true
        running=$((running - 1))
    fi
done
wait || true
status=0
for t in $targets; do
    if [ -f "$rows/$t.row" ]; then cat "$rows/$t.row"; else
        printf '%-24s %14s %8s %s\n' "$t" 0 0 "FAILED: no result (the runner died)"
        status=1
    fi
    [ ! -f "$rows/$t.failed" ] || status=1
done
exit $status
