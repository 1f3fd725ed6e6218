#!/usr/bin/env bash
# The HIL suite proper: runs where vcan0 is up (natively or in the VM; see hil/run.sh).
# Each case starts `antisurge plant` and `antisurge run` on vcan0 with one config, runs the
# scenario in real time, and hil/suite/check.py checks the plant's summary and trace against
# an in-process `antisurge sim` run of the same plant, scenario and law.
#
#   hil/suite/inside.sh [CASE...]     cases: recycle_pi drive_torque kill9 link_bounce malformed timing
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=${ANTISURGE_BIN:-target/release/antisurge}
out=${ANTISURGE_HIL_OUT:-out/hil}
iface=vcan0
cases=("$@")
[[ ${#cases[@]} -gt 0 ]] || cases=(recycle_pi drive_torque kill9 link_bounce malformed timing)
mkdir -p "$out"
tmp_candump=${TMPDIR:-/tmp}/antisurge-hil-candump.$$.log
echo "HIL suite on $iface (${ANTISURGE_HIL_INSIDE:-?}), cases: ${cases[*]}"

# run_case NAME CONFIG ACTION: plant + controller on vcan0; ACTION runs in the background
# during the scenario (none | kill9 | link_bounce | malformed | timing).
run_case() {
    local name=$1 cfg=$2 action=$3
    local dir=$out/$name
    rm -rf "$dir"; mkdir -p "$dir"
    export ANTISURGE_EVENT_LOG__PATH="$PWD/$dir/events.jsonl"
    export ANTISURGE_STATUS__STATS_FILE="$PWD/$dir/controller_stats.json"
    "$bin" plant --config "$cfg" --out "$dir/plant" >"$dir/plant.log" 2>&1 &
    local plant=$!
    sleep 0.5
    "$bin" run --config "$cfg" >"$dir/run.log" 2>&1 &
    local ctl=$!
    case $action in
        kill9) (sleep 6.5; kill -9 "$ctl"; echo "killed controller at +6.5 s") >"$dir/action.log" 2>&1 & ;;
        link_bounce) (sleep 9; ip link set "$iface" down; echo "down"; sleep 0.5; ip link set "$iface" up; echo "up") >"$dir/action.log" 2>&1 & ;;
        timing)
            # measured beside the loops, at their priority: cyclictest, and every frame on the bus
            (cyclictest -m -p "$(awk -F' *= *' '/^priority/ {print $2}' "$cfg")" -i 1000 -D 18 -q -h 20000 \
                >"$dir/cyclictest.txt" 2>&1) &
            # (kernel receive timestamps; a large socket buffer, a real-time priority below the
            # loops' and a local file (not the VM's shared folder) so that it drops nothing)
            sysctl -q -w net.core.rmem_max=16777216 2>/dev/null || true
            (timeout 20 chrt -f 50 candump -t a -r 16777216 -d vcan0 >"$tmp_candump" 2>"$dir/candump.err") & ;;
        malformed) python3 hil/suite/malformed.py "$iface" 300 "$(date -d '+8 seconds' +%s.%N)" >"$dir/action.log" 2>&1 & ;;
    esac
    local rc=0
    wait "$plant" || rc=$?
    kill -TERM "$ctl" 2>/dev/null || true
    wait "$ctl" 2>/dev/null || true
    wait || true
    [[ ! -f $tmp_candump ]] || mv "$tmp_candump" "$dir/candump.log"
    unset ANTISURGE_EVENT_LOG__PATH ANTISURGE_STATUS__STATS_FILE
    if [[ $rc -ne 0 ]]; then
        echo "FAIL $name: plant exit $rc"; tail -20 "$dir/plant.log" "$dir/run.log"; return 1
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
        *) echo "unknown case $c"; fail=1 ;;
    esac
done
[[ $fail -eq 0 ]] && echo "HIL suite: all cases passed" || echo "HIL suite: FAILED"
exit $fail
