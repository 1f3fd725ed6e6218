#!/usr/bin/env bash
# HIL suite entry point (CI runs this): builds the release binary if needed, makes sure the VM
# harness is set up when the host kernel lacks vcan, and runs hil/suite/inside.sh where vcan0
# is up (natively if the host kernel has vcan, else in the qemu VM).
#
#   hil/suite.sh [CASE...]
set -euo pipefail
cd "$(dirname "$0")/.."
[[ -x target/release/antisurge ]] || cargo build --release
if ! ip link show vcan0 >/dev/null 2>&1 && ! { [[ $(id -u) == 0 ]] && modprobe -q vcan 2>/dev/null; }; then
    hil/vm/setup.sh
fi
# In the VM, guest time is virtual (qemu -icount): it advances with the instructions the guest
# runs, so host scheduling stalls do not reach the real-time loops as late wake-ups. One vCPU
# (icount runs single-threaded TCG) at 2 ns per instruction: cyclictest there shows a few µs.
export ANTISURGE_HIL_ICOUNT=${ANTISURGE_HIL_ICOUNT-shift=1,sleep=off}
export ANTISURGE_HIL_CPUS=${ANTISURGE_HIL_CPUS:-1}
exec hil/run.sh --timeout 900 --mem 2048 -- hil/suite/inside.sh "$@"
