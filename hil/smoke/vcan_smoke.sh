#!/usr/bin/env bash
# HIL self-check: virtual CAN works where hil/run.sh runs commands.
#
#   hil/smoke/vcan_smoke.sh          # from the host: goes through hil/run.sh
#   hil/run.sh -- hil/smoke/vcan_smoke.sh
#
# Checks, on vcan0: candump receives a standard-id and an extended-id frame
# sent with cansend, with the right data (and nothing sent on vcan1);
# `ip link set vcan0 down` makes sending fail and `up` makes it work again.
# Also checks the environment HIL commands rely on: lo up, writable /tmp and
# /dev/shm, a sane clock, and (from the host) that files written inside show
# up in the repository and that the environment is passed through.
# Prints "vcan_smoke: N passed, M failed" last; exit status 0 only if all pass.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
repo=$(cd "$here/../.." && pwd -P)

if [[ -z ${ANTISURGE_HIL_INSIDE:-} ]]; then
    # Outer half, on the host: run the checks through hil/run.sh, then verify
    # what only the host can see.
    nonce=$RANDOM$RANDOM$RANDOM
    marker=$repo/hil/.cache/smoke/marker
    mkdir -p "$(dirname "$marker")"
    rm -f "$marker"
    t0=$EPOCHREALTIME
    rc=0
    VCAN_SMOKE_NONCE=$nonce VCAN_SMOKE_HOST_EPOCH=$(date +%s) \
        "$repo/hil/run.sh" "$@" -- "$here/vcan_smoke.sh" || rc=$?
    if [[ $rc == 0 ]]; then
        if [[ -f $marker && $(cat "$marker") == "$nonce" ]]; then
            echo "ok: file written inside is visible on the host, environment passed through"
        else
            echo "FAIL: $marker missing or without the nonce"
            rc=1
        fi
    fi
    awk -v s="$t0" -v e="$EPOCHREALTIME" 'BEGIN { printf "vcan_smoke: wall time %.1f s\n", e - s }'
    exit "$rc"
fi

# Inner half: runs where vcan0 is (host or VM).
passed=0
failed=0
ok() { echo "ok: $*"; passed=$((passed + 1)); }
bad() { echo "FAIL: $*"; failed=$((failed + 1)); }
check() {
    local what=$1
    shift
    if "$@"; then ok "$what"; else bad "$what"; fi
}

tmp=$(mktemp -d)
pids=()
cleanup() {
    local p
    for p in "${pids[@]}"; do
        kill "$p" 2>/dev/null || true
    done
    rm -rf "$tmp"
}
trap cleanup EXIT

echo "vcan_smoke: running in '${ANTISURGE_HIL_INSIDE}' mode, kernel $(uname -r)"
# Under qemu -icount with sleep=off (the single CI boot, see hil/suite.sh) guest time jumps
# ahead while the guest waits for the host: the first exec of a tool pulls it over the shared
# filesystem in host time while the guest's timers (candump's `timeout`, the start wait below)
# run out in guest time. Read the tools once first, so no wait below spans a cold load.
for tool in candump cansend ip timeout; do
    p=$(command -v "$tool" 2>/dev/null) && cat "$p" >/dev/null
done
candump -h >/dev/null 2>&1 || true
cansend -h >/dev/null 2>&1 || true

# --- environment ----------------------------------------------------------
check "vcan0 is a vcan interface and up" \
    bash -c 'ip -details link show dev vcan0 | grep -qw vcan && ip link show dev vcan0 | grep -q "[<,]UP[,>]"'
check "lo is up" bash -c 'ip link show dev lo | grep -q "[<,]UP[,>]"'
check "/tmp is writable" bash -c "echo x >'$tmp/w' && [[ \$(cat '$tmp/w') == x ]]"
# shellcheck disable=SC2016  # expanded by the inner bash
check "/dev/shm is writable" bash -c 'f=/dev/shm/vcan_smoke.$$; echo x >"$f" && rm "$f"'
if [[ -n ${VCAN_SMOKE_HOST_EPOCH:-} ]]; then
    now=$(date +%s)
    check "clock is sane (host said $VCAN_SMOKE_HOST_EPOCH, here $now)" \
        test "$now" -ge $((VCAN_SMOKE_HOST_EPOCH - 5)) -a "$now" -le $((VCAN_SMOKE_HOST_EPOCH + 900))
fi

# --- frames ---------------------------------------------------------------
# Number of CAN_RAW receivers registered on vcan0 (-1 if unknown).
receivers() {
    if [[ -r /proc/net/can/rcvlist_all ]]; then
        grep -cE '^ +vcan0 ' /proc/net/can/rcvlist_all || true
    else
        echo -1
    fi
}

# Wait until candump (pid $1) has bound its socket, i.e. the receiver count
# on vcan0 exceeds $2, so that no frame sent afterwards is lost.
wait_bound() {
    local pid=$1 before=$2 i
    for i in $(seq 100); do
        kill -0 "$pid" 2>/dev/null || return 1
        if [[ $before -lt 0 ]]; then
            [[ $i -ge 5 ]] && return 0   # no procfs view: fixed 0.5 s
        elif [[ $(receivers) -gt $before ]]; then
            return 0
        fi
        sleep 0.1
    done
    return 1
}

# $1 = expected frame count; remaining args are cansend calls "IFACE FRAME".
# Writes candump's log lines to $tmp/dump.
dump_and_send() {
    local count=$1 f
    shift
    : >"$tmp/dump"
    local before
    before=$(receivers)
    timeout 10 candump -L -n "$count" vcan0 >"$tmp/dump" 2>"$tmp/dump.err" &
    local dpid=$!
    pids+=("$dpid")
    if ! wait_bound "$dpid" "$before"; then
        echo "candump did not start: $(cat "$tmp/dump.err")"
        return 1
    fi
    for f in "$@"; do
        # shellcheck disable=SC2086
        cansend $f || { echo "cansend $f failed"; return 1; }
    done
    wait "$dpid" || { echo "candump exited with $? (got: $(cat "$tmp/dump"))"; return 1; }
}

if dump_and_send 2 "vcan0 123#DEADBEEF" "vcan1 321#11" "vcan0 1ABCDEF0#0102030405060708"; then
    sed 's/^/  candump: /' "$tmp/dump"
    check "standard frame 123#DEADBEEF received" grep -qE ' vcan0 123#DEADBEEF$' "$tmp/dump"
    check "extended frame 1ABCDEF0#0102030405060708 received" \
        grep -qE ' vcan0 1ABCDEF0#0102030405060708$' "$tmp/dump"
    check "exactly two frames on vcan0, none from vcan1" test "$(wc -l <"$tmp/dump")" -eq 2
else
    bad "candump/cansend on vcan0"
fi

# --- link down / up -------------------------------------------------------
if ip link set dev vcan0 down; then
    ok "ip link set vcan0 down"
    check "vcan0 reports down" bash -c '! ip link show dev vcan0 | grep -q "[<,]UP[,>]"'
    if cansend vcan0 555#AA 2>"$tmp/down.err"; then
        bad "cansend on a down vcan0 should fail"
    else
        ok "cansend on a down vcan0 fails ($(tr -d '\n' <"$tmp/down.err"))"
    fi
else
    bad "ip link set vcan0 down"
fi
if ip link set dev vcan0 up; then
    ok "ip link set vcan0 up"
    if dump_and_send 1 "vcan0 7FF#CAFE"; then
        check "frame received after up" grep -qE ' vcan0 7FF#CAFE$' "$tmp/dump"
    else
        bad "candump/cansend after up"
    fi
else
    bad "ip link set vcan0 up"
fi

# --- shared repository ----------------------------------------------------
if [[ -n ${VCAN_SMOKE_NONCE:-} ]]; then
    mkdir -p "$repo/hil/.cache/smoke"
    check "write into the repository" \
        bash -c "printf '%s\n' '$VCAN_SMOKE_NONCE' >'$repo/hil/.cache/smoke/marker'"
fi

echo "vcan_smoke: $passed passed, $failed failed"
[[ $failed == 0 ]]
