#!/usr/bin/env bash
# The HIL suite proper: runs where vcan0 is up (natively or in the VM; see hil/run.sh).
# Each case starts `antisurge plant` and `antisurge run` on vcan0 with one config, runs the
# scenario in real time, and hil/suite/check.py checks the plant's summary and trace against
# an in-process `antisurge sim` run of the same plant, scenario and law.
#
#   hil/suite/inside.sh [CASE...]     cases: recycle_pi drive_torque kill9 link_bounce malformed timing
#                                            foreign_dbc plant_pause
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=${ANTISURGE_BIN:-target/release/antisurge}
out=${ANTISURGE_HIL_OUT:-out/hil}
iface=vcan0
cases=("$@")
[[ ${#cases[@]} -gt 0 ]] || cases=(recycle_pi drive_torque kill9 link_bounce malformed timing foreign_dbc plant_pause)
mkdir -p "$out"
tmp_candump=${TMPDIR:-/tmp}/antisurge-hil-candump.$$.log
echo "HIL suite on $iface (${ANTISURGE_HIL_INSIDE:-?}), cases: ${cases[*]}"

# Every wait below is bounded: a process that does not end in time is shown (each thread's
# state, kernel wait channel and stack, the tail of its log) and killed, and the case fails.
# Limits are in guest seconds; a 20-s scenario ends in about 22.
plant_limit_s=${ANTISURGE_HIL_CASE_LIMIT_S:-90}
stop_limit_s=15
t_suite=$SECONDS

# show_proc PID: what PID and its threads are doing (for a hang report).
show_proc() {
    local pid=$1 t
    echo "  process $pid: $(tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null)"
    for t in /proc/"$pid"/task/*; do
        [[ -d $t ]] || continue
        echo "    thread ${t##*/} $(cat "$t/comm" 2>/dev/null): state $(awk '{print $3}' "$t/stat" 2>/dev/null), wchan $(cat "$t/wchan" 2>/dev/null)"
        sed 's/^/      /' "$t/stack" 2>/dev/null | head -12
    done
}

# wait_bounded PID LIMIT_S WHAT LOG: PID's exit status, or 124 after LIMIT_S seconds (PID is
# then shown and killed). One watchdog per wait: no polling beside the real-time loops.
wait_bounded() {
    local pid=$1 limit_s=$2 what=$3 log=${4:-}
    local mark=${TMPDIR:-/tmp}/antisurge-hil-timeout.$$.$pid
    # $done says "PID was reaped": the dog trusts it rather than `kill -0` (a dog that outlives its
    # wait, e.g. when SIGTERM is ignored in this shell, must not report a process that has exited).
    local done=$mark.reaped
    rm -f "$mark" "$done"
    (
        sleep "$limit_s"
        [[ ! -e $done ]] || exit 0
        kill -0 "$pid" 2>/dev/null || exit 0
        {
            echo "FAIL: $what still running after ${limit_s} s; killed. What it was doing:"
            show_proc "$pid"
            [[ -z $log || ! -f $log ]] || { echo "  last lines of $log:"; tail -15 "$log" | sed 's/^/    /'; }
        } >&2
        touch "$mark"
        kill -KILL "$pid" 2>/dev/null
    ) &
    local dog=$! rc=0
    wait "$pid" || rc=$?
    touch "$done"
    kill -KILL "$dog" 2>/dev/null || true
    wait "$dog" 2>/dev/null || true
    if [[ -f $mark ]]; then
        rm -f "$mark"
        return 124
    fi
    return "$rc"
}

# run_case NAME CONFIG ACTION: plant + controller on vcan0; ACTION runs in the background
# during the scenario (none | kill9 | link_bounce | malformed | timing | plant_pause).
run_case() {
    local name=$1 cfg=$2 action=$3
    local dir=$out/$name t0=$SECONDS
    rm -rf "$dir"; mkdir -p "$dir"
    echo "case $name: starting (+$((t0 - t_suite)) s)" >&2
    export ANTISURGE_EVENT_LOG__PATH="$PWD/$dir/events.jsonl"
    export ANTISURGE_STATUS__STATS_FILE="$PWD/$dir/controller_stats.json"
    # each case its own persistent state: surge counter and safety-on shifts kept by an
    # earlier case (or by the test suite in ./out/state) would move this case's control line
    export ANTISURGE_STATUS__STATE_DIR="$PWD/$dir/state"
    # the status socket on a local file system: the VM's shared folder cannot hold a Unix
    # socket (bind: ENXIO), and a daemon that cannot bind an operator surface does not start
    local sock_dir
    sock_dir=$(mktemp -d "${TMPDIR:-/tmp}/antisurge-hil-status.XXXXXX")
    export ANTISURGE_STATUS__SOCKET="$sock_dir/status.sock"
    "$bin" plant --config "$cfg" --out "$dir/plant" >"$dir/plant.log" 2>&1 &
    local plant=$!
    sleep 0.5
    "$bin" run --config "$cfg" >"$dir/run.log" 2>&1 &
    local ctl=$! act=""
    case $action in
        kill9) (sleep 6.5; kill -9 "$ctl"; echo "killed controller at +6.5 s") >"$dir/action.log" 2>&1 & act=$! ;;
        link_bounce) (sleep 9; ip link set "$iface" down; echo "down"; sleep 0.5; ip link set "$iface" up; echo "up") >"$dir/action.log" 2>&1 & act=$! ;;
        timing)
            # measured beside the loops, at their priority: cyclictest, and every frame on the bus
            (cyclictest -m -p "$(awk -F' *= *' '/^priority/ {print $2}' "$cfg")" -i 1000 -D 18 -q -h 20000 \
                >"$dir/cyclictest.txt" 2>&1) &
            act=$!
            # (kernel receive timestamps; a large socket buffer, a real-time priority below the
            # loops' and a local file (not the VM's shared folder) so that it drops nothing)
            sysctl -q -w net.core.rmem_max=16777216 2>/dev/null || true
            (timeout 20 chrt -f 50 candump -t a -r 16777216 -d vcan0 >"$tmp_candump" 2>"$dir/candump.err") &
            act="$act $!" ;;
        plant_pause)
            # the plant's host stops it for a few ms, 8 times through the closure (SIGSTOP: all
            # its threads; its loop then skips the deadlines it missed, so plant time stands
            # still): the samples stay one plant period apart while their arrivals are not.
            # Before the sender's clock (CI 2026-11-29) one such pause of 3.4 ms surged the
            # drive-torque pair.
            # (hil/suite/pause.py: a shell's fork of `sleep` stopped it for 64 ms in the VM; at
            # FIFO 60, below the bus threads' 70: at 70 its exit starved them for 43 ms)
            chrt -f 60 python3 hil/suite/pause.py "$plant" 5.6 8 0.2 0.004 >"$dir/action.log" 2>&1 & act=$! ;;
        malformed) python3 hil/suite/malformed.py "$iface" 300 "$(date -d '+8 seconds' +%s.%N)" >"$dir/action.log" 2>&1 & act=$! ;;
    esac
    local rc=0
    wait_bounded "$plant" "$plant_limit_s" "the plant node ($name)" "$dir/plant.log" || rc=$?
    kill -TERM "$ctl" 2>/dev/null || true
    local crc=0
    wait_bounded "$ctl" "$stop_limit_s" "the controller, after SIGTERM ($name)" "$dir/run.log" || crc=$?
    local p
    for p in $act; do
        wait_bounded "$p" "$stop_limit_s" "the $action action ($name)" "$dir/action.log" || true
    done
    [[ ! -f $tmp_candump ]] || mv "$tmp_candump" "$dir/candump.log"
    unset ANTISURGE_EVENT_LOG__PATH ANTISURGE_STATUS__STATS_FILE ANTISURGE_STATUS__STATE_DIR \
        ANTISURGE_STATUS__SOCKET
    rm -rf "$sock_dir"
    echo "case $name: scenario over after $((SECONDS - t0)) s" >&2
    if [[ $rc -ne 0 ]]; then
        echo "FAIL $name: plant exit $rc"; tail -n 20 "$dir/plant.log" "$dir/run.log"; return 1
    fi
    if [[ $crc -eq 124 ]]; then
        echo "FAIL $name: the controller did not stop within $stop_limit_s s of SIGTERM"; return 1
    fi
    python3 hil/suite/check.py "$name" "$dir" "$bin"
}

fail=0
for c in "${cases[@]}"; do
    case $c in
        recycle_pi) run_case recycle_pi hil/configs/can_recycle_pi.toml none || fail=1 ;;
        drive_torque) run_case drive_torque hil/configs/can_drive_torque.toml none || fail=1 ;;
        kill9) run_case kill9 hil/configs/can_recycle_pi.toml kill9 || fail=1 ;;
        link_bounce) run_case link_bounce hil/configs/can_recycle_pi.toml link_bounce || fail=1 ;;
        malformed) run_case malformed hil/configs/can_recycle_pi.toml malformed || fail=1 ;;
        timing) run_case timing hil/configs/can_drive_torque.toml timing || fail=1 ;;
        # a foreign-style DBC (tests/fixtures/foreign_skid/skid_foreign.dbc): % valve, bar, rpm,
        # a 29-bit Motorola message, the skid's 16-bit watchdog counter as the heartbeat
        foreign_dbc) run_case foreign_dbc hil/configs/can_foreign_dbc.toml none || fail=1 ;;
        plant_pause) run_case plant_pause hil/configs/can_drive_torque.toml plant_pause || fail=1 ;;
        *) echo "unknown case $c"; fail=1 ;;
    esac
done
[[ $fail -eq 0 ]] && echo "HIL suite: all cases passed" || echo "HIL suite: FAILED"
exit $fail
