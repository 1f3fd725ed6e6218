#!/usr/bin/env bash
# Entry point of the HIL suite: run a command where virtual CAN works.
#
#   hil/run.sh [VM-OPTIONS] -- COMMAND [ARGS...]
#
# If the host kernel supports vcan (an existing vcan0, or root can create
# one), the vcan interfaces are created / brought up natively and COMMAND runs
# right here. Otherwise COMMAND runs inside the QEMU VM of hil/vm/run-in-vm.sh
# (see there for VM-OPTIONS: --cpus --mem --timeout --rw --no-overlay
# --verbose --quiet; they are ignored on the native path except --timeout).
# Either way COMMAND starts in the current directory with vcan0 and vcan1
# (ANTISURGE_HIL_VCAN) up, ANTISURGE_HIL_INSIDE set to "native" or "vm",
# and its exit status is this script's exit status.
#
# Environment:
#   ANTISURGE_HIL_MODE=auto|native|vm   default auto
#   ANTISURGE_HIL_FORCE_VM=1            same as ANTISURGE_HIL_MODE=vm
#   ANTISURGE_HIL_VCAN="vcan0 vcan1"    interfaces to provide
# Interfaces created on the native path are deleted again at exit; existing
# ones are left alone.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
# shellcheck source-path=SCRIPTDIR source=lib/vcan.sh
. "$here/lib/vcan.sh"

usage() {
    sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'
    exit "${1:-2}"
}

vm_opts=()
timeout_s=""
while [[ $# -gt 0 ]]; do
    case $1 in
        --cpus|--mem|--rw) vm_opts+=("$1" "${2:?$1 needs a value}"); shift 2 ;;
        --timeout) timeout_s=${2:?--timeout needs a value}; vm_opts+=("$1" "$2"); shift 2 ;;
        --no-overlay|--verbose|--quiet) vm_opts+=("$1"); shift ;;
        -h|--help) usage 0 ;;
        --) shift; break ;;
        *) echo "run.sh: unknown option: $1" >&2; usage 2 ;;
    esac
done
[[ $# -gt 0 ]] || usage 2

mode=${ANTISURGE_HIL_MODE:-auto}
[[ ${ANTISURGE_HIL_FORCE_VM:-0} == 1 ]] && mode=vm
case $mode in
    auto|native|vm) ;;
    *) echo "run.sh: ANTISURGE_HIL_MODE must be auto, native or vm" >&2; exit 2 ;;
esac
read -r -a vcans <<<"${ANTISURGE_HIL_VCAN:-$HIL_VCAN_IFACES_DEFAULT}"

created=()
native_ready() {
    local out
    if [[ $(id -u) == 0 ]]; then
        # Loads vcan where it is a module; harmless where it is not.
        modprobe -q vcan 2>/dev/null || true
    fi
    out=$(hil_vcan_up "${vcans[@]}" 2>/dev/null) || {
        mapfile -t created <<<"$out"
        return 1
    }
    [[ -n $out ]] && mapfile -t created <<<"$out"
    return 0
}
remove_created() {
    local ifc
    for ifc in "${created[@]}"; do
        [[ -n $ifc ]] && ip link delete dev "$ifc" 2>/dev/null
    done
    return 0
}

if [[ $mode != vm ]]; then
    if native_ready; then
        trap remove_created EXIT
        export ANTISURGE_HIL_INSIDE=native
        rc=0
        if [[ -n $timeout_s ]]; then
            timeout --kill-after=5 "$timeout_s" "$@" || rc=$?
        else
            "$@" || rc=$?
        fi
        exit "$rc"
    fi
    remove_created
    created=()
    if [[ $mode == native ]]; then
        echo "run.sh: the host kernel cannot provide vcan (${vcans[*]}) and ANTISURGE_HIL_MODE=native" >&2
        exit 125
    fi
fi

exec "$here/vm/run-in-vm.sh" "${vm_opts[@]}" -- "$@"
