#!/usr/bin/env bash
# Run a command inside a throwaway QEMU (TCG) virtual machine whose kernel has
# virtual CAN, with the host's filesystem shared into it.
#
#   hil/vm/run-in-vm.sh [OPTIONS] -- COMMAND [ARGS...]
#
# Options (defaults in parentheses, or from the environment variable named):
#   --cpus N       guest CPUs               (2, ANTISURGE_HIL_CPUS)
#   --mem MB       guest memory in MiB      (1024, ANTISURGE_HIL_MEM)
#   --timeout S    hard limit for the whole VM run, boot included; qemu is
#                  killed and the script exits 124 (600, ANTISURGE_HIL_TIMEOUT)
#   --rw DIR       also share DIR read-write (repeatable; the repository is
#                  always shared read-write)
#   --no-overlay   plain read-only root instead of a tmpfs overlay on top
#   --verbose      kernel log level 7 and the serial console copied to stderr
#                  live (also ANTISURGE_HIL_VERBOSE=1)
#   --quiet        no timing line on stderr at the end
#
# Inside the guest the host's root filesystem is mounted read-only (writes
# land in a throwaway tmpfs overlay), the repository read-write at the same
# path, /proc /sys /dev /dev/shm /tmp /run are fresh, lo and the vcan
# interfaces (ANTISURGE_HIL_VCAN, default "vcan0 vcan1") are up, and COMMAND
# runs as root from the current directory with the host's environment. Its
# stdout and stderr are streamed to this script's stdout and stderr; stdin is
# /dev/null.
#
# Exit status: COMMAND's; 124 on timeout; 125 if the VM itself failed (the
# tail of the serial console log is printed then). Logs of the last runs are
# kept in ${ANTISURGE_HIL_CACHE:-hil/.cache}/logs/.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
repo=$(cd "$here/../.." && pwd -P)
cache=${ANTISURGE_HIL_CACHE:-$repo/hil/.cache}

cpus=${ANTISURGE_HIL_CPUS:-2}
mem=${ANTISURGE_HIL_MEM:-1024}
timeout_s=${ANTISURGE_HIL_TIMEOUT:-600}
verbose=${ANTISURGE_HIL_VERBOSE:-0}
quiet=0
overlay=1
rw_dirs=("$repo")

usage() {
    sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'
    exit "${1:-2}"
}
die() { printf '[hil-vm] error: %s\n' "$*" >&2; exit 125; }
note() { printf '[hil-vm] %s\n' "$*" >&2; }

while [[ $# -gt 0 ]]; do
    case $1 in
        --cpus) cpus=${2:?--cpus needs a value}; shift 2 ;;
        --mem) mem=${2:?--mem needs a value}; shift 2 ;;
        --timeout) timeout_s=${2:?--timeout needs a value}; shift 2 ;;
        --rw) rw_dirs+=("$(cd "${2:?--rw needs a directory}" && pwd -P)"); shift 2 ;;
        --no-overlay) overlay=0; shift ;;
        --verbose) verbose=1; shift ;;
        --quiet) quiet=1; shift ;;
        -h|--help) usage 0 ;;
        --) shift; break ;;
        *) echo "run-in-vm.sh: unknown option: $1" >&2; usage 2 ;;
    esac
done
[[ $# -gt 0 ]] || usage 2
[[ $cpus =~ ^[1-9][0-9]*$ ]] || die "--cpus must be a positive integer"
[[ $mem =~ ^[1-9][0-9]*$ ]] || die "--mem must be a positive integer (MiB)"
[[ $timeout_s =~ ^[1-9][0-9]*$ ]] || die "--timeout must be a positive integer (seconds)"

vcan_list=${ANTISURGE_HIL_VCAN:-vcan0 vcan1}
for ifc in $vcan_list; do
    [[ $ifc =~ ^[A-Za-z0-9_.-]{1,15}$ ]] || die "bad interface name in ANTISURGE_HIL_VCAN: '$ifc'"
done

# Build or check the kernel and initramfs (fast when cached).
"$here/setup.sh" --quiet || die "hil/vm/setup.sh failed"
command -v qemu-system-x86_64 >/dev/null || die "qemu-system-x86_64 not found"

t_start=$EPOCHREALTIME

# Per-run job directory, shared with the guest as "hiljob".
job=$(mktemp -d "${TMPDIR:-/tmp}/antisurge-hil.XXXXXX")
logdir=$cache/logs
mkdir -p "$logdir"
logbase=$logdir/vm-$(date +%Y%m%d-%H%M%S)-$$
serial_log=$logbase.serial.log
qemu_log=$logbase.qemu.log
: >"$serial_log"
ln -sfn "$(basename "$serial_log")" "$logdir/latest.serial.log"

pids=()
qemu_pid=""
# shellcheck disable=SC2317  # invoked by the EXIT trap
cleanup() {
    local p
    if [[ -n $qemu_pid ]]; then
        kill "$qemu_pid" 2>/dev/null || true
    fi
    for p in "${pids[@]}"; do
        kill "$p" 2>/dev/null || true
    done
    rm -rf "$job"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

sq() { printf "'%s'" "${1//\'/\'\\\'\'}"; }
{
    echo "HIL_REPO=$(sq "$repo")"
    echo "HIL_CWD=$(sq "$PWD")"
    echo "HIL_STAGE2=$(sq "$here/guest-stage2.sh")"
    echo "HIL_OVERLAY=$overlay"
    echo "HIL_TRACE=${ANTISURGE_HIL_TRACE:-0}"
    echo "HIL_VCAN=$(sq "$vcan_list")"
    echo "HIL_RW_N=${#rw_dirs[@]}"
    for i in "${!rw_dirs[@]}"; do
        echo "HIL_RW_$i=$(sq "${rw_dirs[$i]}")"
    done
} >"$job/config"
env -0 >"$job/env"
printf '%s\0' "$@" >"$job/cmd"

# The guest's stdout/stderr/control ports end in FIFOs read here; the
# readers must be running before qemu opens the FIFOs. If our stdout or
# stderr goes away (`... | head`), a relay keeps draining its FIFO so that
# the guest never blocks on a full port.
relay() {
    trap '' PIPE
    exec 3<"$1"
    cat <&3 2>/dev/null || cat <&3 >/dev/null
}
mkfifo "$job/stdout" "$job/stderr" "$job/ctl"
: >"$job/ctl.log"
relay "$job/stdout" &
pids+=($!)
relay "$job/stderr" >&2 &
pids+=($!)
while IFS= read -r line; do
    printf '%s %s\n' "$EPOCHREALTIME" "$line"
done <"$job/ctl" >"$job/ctl.log" &
pids+=($!)

loglevel=4
[[ $verbose == 1 ]] && loglevel=7
append="console=ttyS0 loglevel=$loglevel panic=-1 rdinit=/init mitigations=off"
# pci=noacpi: IRQ routing from the BIOS table; enabling the ACPI PCI
# interrupt links costs ~1 s under TCG.
append+=" pci=noacpi 8250.nr_uarts=1 random.trust_cpu=on ${ANTISURGE_HIL_KERNEL_ARGS:-}"
# Under TCG every vCPU reads the host's TSC; if the host trusts its TSC, the
# guest may too (vDSO clock reads instead of HPET: ~2x cheaper).
if [[ $(cat /sys/devices/system/clocksource/clocksource0/current_clocksource 2>/dev/null) == tsc ]]; then
    append+=" tsc=reliable"
fi
kernel=$cache/vm/vmlinux
[[ -f $kernel ]] || kernel=$cache/vm/vmlinuz

# shellcheck disable=SC2054  # the commas are qemu's
# Clock: by default guest time is host time (multi-threaded TCG). With ANTISURGE_HIL_ICOUNT
# (e.g. "shift=2,sleep=off"), guest time is virtual and advances with the instructions the
# guest executes (2^shift ns each): host scheduling hiccups no longer show in the guest as
# late wake-ups, so real-time loops in the VM behave as on a dedicated machine (single-
# threaded TCG: slower in wall time).
if [[ -n ${ANTISURGE_HIL_ICOUNT:-} ]]; then
    accel=(-accel tcg,thread=single -icount "$ANTISURGE_HIL_ICOUNT")
else
    accel=(-accel tcg,thread=multi)
fi
qemu=(
    qemu-system-x86_64
    "${accel[@]}" -machine pc -cpu max
    -smp "$cpus" -m "$mem"
    -nodefaults -no-user-config -display none -no-reboot
    -rtc base=utc
    -kernel "$kernel" -initrd "$cache/vm/initramfs.cpio"
    -append "$append"
    -chardev "file,id=con,path=$serial_log" -serial chardev:con
    -device virtio-rng-pci
    -device virtio-serial-pci,id=vser
    -chardev "file,id=out,path=$job/stdout"
    -device virtserialport,bus=vser.0,chardev=out,name=hil.stdout
    -chardev "file,id=err,path=$job/stderr"
    -device virtserialport,bus=vser.0,chardev=err,name=hil.stderr
    -chardev "file,id=ctl,path=$job/ctl"
    -device virtserialport,bus=vser.0,chardev=ctl,name=hil.ctl
    -fsdev "local,id=fsroot,path=/,security_model=none,readonly=on,multidevs=remap"
    -device virtio-9p-pci,fsdev=fsroot,mount_tag=hilroot
    -fsdev "local,id=fsjob,path=$job,security_model=none"
    -device virtio-9p-pci,fsdev=fsjob,mount_tag=hiljob
)
for i in "${!rw_dirs[@]}"; do
    qemu+=(
        -fsdev "local,id=fsrw$i,path=${rw_dirs[$i]},security_model=none,multidevs=remap"
        -device "virtio-9p-pci,fsdev=fsrw$i,mount_tag=hilrw$i"
    )
done

"${qemu[@]}" </dev/null >"$qemu_log" 2>&1 &
qemu_pid=$!
if [[ $verbose == 1 ]]; then
    tail -n +1 -f --pid="$qemu_pid" "$serial_log" >&2 &
    pids+=($!)
fi

# Hard timeout: a watchdog kills qemu and leaves a mark.
(
    sleep "$timeout_s"
    touch "$job/timed-out"
    kill -TERM "$qemu_pid" 2>/dev/null
    sleep 5
    kill -KILL "$qemu_pid" 2>/dev/null
) </dev/null >/dev/null 2>&1 &
watchdog=$!
pids+=("$watchdog")

qrc=0
wait "$qemu_pid" || qrc=$?
qemu_pid=""
kill "$watchdog" 2>/dev/null || true
t_end=$EPOCHREALTIME

# Readers end by themselves once qemu has closed the FIFOs; if qemu died
# before opening them, they are still blocked in open(): stop them.
for _ in $(seq 20); do
    alive=0
    for p in "${pids[@]}"; do
        kill -0 "$p" 2>/dev/null && alive=1
    done
    [[ $alive == 0 ]] && break
    sleep 0.1
done
for p in "${pids[@]}"; do
    kill "$p" 2>/dev/null || true
done
wait 2>/dev/null || true
pids=()

if [[ -f $job/dmesg.txt ]]; then
    cp "$job/dmesg.txt" "$logbase.dmesg.txt"
fi
cp "$job/ctl.log" "$logbase.ctl.log"
# Keep the logs of the last 20 runs.
mapfile -t old < <(find "$logdir" -maxdepth 1 -name 'vm-*.serial.log' -printf '%T@ %p\n' \
    | sort -rn | tail -n +21 | cut -d' ' -f2-)
for f in "${old[@]}"; do
    rm -f "${f%.serial.log}".*
done

show_failure() {
    note "$1"
    if [[ -f $job/init-error ]]; then
        note "guest init: $(cat "$job/init-error")"
    fi
    if [[ -f $job/stage2-error ]]; then
        note "guest stage 2: $(cat "$job/stage2-error")"
    fi
    note "serial console ($serial_log), last 40 lines:"
    tail -n 40 "$serial_log" | sed 's/^/  | /' >&2
    if [[ -s $qemu_log ]]; then
        note "qemu output ($qemu_log):"
        tail -n 20 "$qemu_log" | sed 's/^/  | /' >&2
    fi
    [[ -f $logbase.dmesg.txt ]] && note "full kernel log: $logbase.dmesg.txt"
    return 0
}

# Timings from the control channel (host clock).
t_init="" t_cmd="" t_exit=""
while read -r ts what _; do
    case $what in
        init) t_init=$ts ;;
        start) t_cmd=$ts ;;
        exit) t_exit=$ts ;;
    esac
done <"$logbase.ctl.log"
timing() {
    awk -v s="$t_start" -v i="$t_init" -v c="$t_cmd" -v x="$t_exit" -v e="$t_end" 'BEGIN {
        out = sprintf("total %.1fs", e - s)
        if (i != "") out = out sprintf(", kernel boot %.1fs", i - s)
        if (c != "") out = out sprintf(", boot-to-command %.1fs", c - s)
        if (c != "" && x != "") out = out sprintf(", command %.1fs", x - c)
        print out
    }'
}

if [[ -f $job/timed-out ]]; then
    show_failure "timed out after ${timeout_s}s ($(timing)); qemu killed"
    exit 124
fi
if [[ ! -f $job/rc ]]; then
    show_failure "the VM ended without an exit status (qemu exit $qrc, $(timing))"
    exit 125
fi
rc=$(cat "$job/rc")
[[ $rc =~ ^[0-9]+$ ]] || { show_failure "bad exit status '$rc' from the guest"; exit 125; }
[[ $quiet == 1 ]] || note "exit $rc; $(timing); serial log $serial_log"
exit "$rc"
