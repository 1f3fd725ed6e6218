#!/usr/bin/env bash
# Everything CI runs where vcan0 is up, in ONE boot of the HIL VM (or natively when the host
# kernel has vcan): the vcan smoke checks, the vcan integration test, the HIL suite. Each part
# prints its duration (guest seconds in the VM: virtual time under qemu -icount).
#
#   hil/run.sh [OPTIONS] -- .ci/hil_inside.sh VCAN_TEST_BINARY
set -euo pipefail
cd "$(dirname "$0")/.."
. .ci/lib.sh
vcan_test=${1:?usage: .ci/hil_inside.sh VCAN_TEST_BINARY}

ci_block "HIL 1/3: vcan smoke (inner half; the host checks the marker after the boot)"
hil/smoke/vcan_smoke.sh

ci_block "HIL 2/3: the vcan integration test (can_bus_vcan, ignored outside HIL)"
ANTISURGE_REQUIRE_VCAN=1 "$vcan_test" --include-ignored --nocapture --test-threads 1

ci_block "HIL 3/3: HIL suite: plant + controller on vcan0 (recycle-pi, drive-torque, kill -9, link bounce, malformed burst)"
hil/suite/inside.sh
ci_block_end
