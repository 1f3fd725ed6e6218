#!/bin/bash
# antisurge HIL guest, stage 2: runs inside the VM, chrooted into the host's
# (read-only, overlaid) root filesystem, started by hil/vm/init with an empty
# environment once lo and the vcan interfaces are up. Not meant to be run by
# hand.
#
#   guest-stage2.sh JOBDIR
#
# JOBDIR (the host's per-run directory, shared read-write) holds:
#   config  shell assignments written by run-in-vm.sh (HIL_CWD, HIL_VCAN, ...)
#   env     the host environment, NUL-separated NAME=value entries
#   cmd     the command, NUL-separated arguments
# and receives:
#   rc      the command's exit status (decimal), written last
set -uo pipefail

job=${1:?usage: guest-stage2.sh JOBDIR}
PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
export PATH

fail() {
    echo "hil-stage2: $*" >&2
    printf '%s\n' "$*" >>"$job/stage2-error"
    exit 125
}

# shellcheck source=/dev/null
. "$job/config" || fail "cannot read $job/config"
if [[ ${HIL_TRACE:-0} == 1 ]]; then
    # Trace with timestamps to the serial console (ANTISURGE_HIL_TRACE=1).
    PS4='+ $EPOCHREALTIME '
    set -x
fi
ctl_dev="" out_dev="" err_dev=""

# virtio serial ports by name -> /dev/vportNpM (no subshells: every fork
# and exec costs under TCG)
for p in /sys/class/virtio-ports/*; do
    case $(<"$p/name") in
        hil.stdout) out_dev=/dev/${p##*/} ;;
        hil.stderr) err_dev=/dev/${p##*/} ;;
        hil.ctl) ctl_dev=/dev/${p##*/} ;;
    esac
done
[[ -n $out_dev && -n $err_dev && -n $ctl_dev ]] || fail "virtio ports missing"
exec 9>"$ctl_dev" || fail "cannot open $ctl_dev"
ctl() { printf '%s\n' "$*" >&9 2>/dev/null || true; }
ctl stage2

# The host environment, minus what describes the host session itself.
while IFS= read -r -d '' kv; do
    name=${kv%%=*}
    [[ $name =~ ^[A-Za-z_][A-Za-z0-9_]*$ ]] || continue
    case $name in
        PWD|OLDPWD|SHLVL|_|HOSTNAME|BASH*|SHELLOPTS|EUID|UID|PPID|GROUPS) continue ;;
        SSH_*|DBUS_SESSION_BUS_ADDRESS|DISPLAY|WAYLAND_DISPLAY) continue ;;
    esac
    export "${kv?}" 2>/dev/null || true
done <"$job/env"
for name in TMPDIR XDG_RUNTIME_DIR; do
    if [[ -n ${!name:-} && ! -d ${!name} ]]; then
        unset "$name"
    fi
done
export ANTISURGE_HIL_INSIDE=vm

mapfile -d '' -t cmd <"$job/cmd"
[[ ${#cmd[@]} -gt 0 ]] || fail "empty command"
cd "${HIL_CWD:-/}" 2>/dev/null || cd "$HIL_REPO" || fail "cannot cd to $HIL_CWD"

# A virtio port can be open only once at a time, but commands often reopen
# /dev/stdout or /dev/stderr (e.g. `echo x >/dev/stderr`). So the command
# writes into FIFOs (made by hil/vm/init) and two relays copy them to the
# ports.
cat /run/hil-stdout >"$out_dev" 9>&- &
relay_out=$!
cat /run/hil-stderr >"$err_dev" 9>&- &
relay_err=$!

ctl "start"
"${cmd[@]}" </dev/null >/run/hil-stdout 2>/run/hil-stderr 9>&-
rc=$?
ctl "exit $rc"

# Let the relays drain; a background process the command left behind may hold
# the FIFOs open, so give up after 5 s. (`read -t` on a FIFO nobody writes to
# is a sleep without an exec.)
exec 8<>/run/hil-sleep
for ((i = 0; i < 100; i++)); do
    kill -0 "$relay_out" 2>/dev/null || kill -0 "$relay_err" 2>/dev/null || break
    read -r -t 0.05 -u 8 _ || true
done
kill "$relay_out" "$relay_err" 2>/dev/null
wait 2>/dev/null

# The host reads this only after the VM has ended.
printf '%s\n' "$rc" >"$job/rc"
exit 0
