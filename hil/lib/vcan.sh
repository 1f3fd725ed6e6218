# shellcheck shell=bash
# Shared helpers for bringing up virtual CAN interfaces (sourced by
# hil/run.sh on the host and by hil/vm/guest-stage2.sh inside the VM).

# Default interfaces every HIL command gets.
# shellcheck disable=SC2034  # used by the scripts that source this file
HIL_VCAN_IFACES_DEFAULT="vcan0 vcan1"

# hil_is_vcan IFACE: true if IFACE exists and is a vcan device.
hil_is_vcan() {
    local info
    info=$(ip -details link show dev "$1" 2>/dev/null) || return 1
    [[ $info =~ [[:space:]]vcan[[:space:]] ]]
}

# hil_vcan_up IFACE...: create the vcan interfaces that do not exist yet and
# bring all of them up. Prints the names of the interfaces it created to
# stdout (one a line), so the caller can delete them later. Returns non-zero
# (after printing a message to stderr) if any interface cannot be made ready.
hil_vcan_up() {
    local ifc
    for ifc in "$@"; do
        if ip link show dev "$ifc" >/dev/null 2>&1; then
            if ! hil_is_vcan "$ifc"; then
                echo "hil: $ifc exists but is not a vcan interface" >&2
                return 1
            fi
        else
            ip link add dev "$ifc" type vcan 2>/dev/null || return 1
            printf '%s\n' "$ifc"
        fi
        if ! ip link set dev "$ifc" up; then
            echo "hil: cannot bring $ifc up" >&2
            return 1
        fi
    done
}
