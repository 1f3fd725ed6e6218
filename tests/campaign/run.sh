#!/usr/bin/env bash
# The fault campaign of issue 12 against the release binary: kill -9 storm while logging and
# rotating, disk full, file-size limit, unusable log directory, FIFO / /dev/zero / 128 MiB /
# half-written config, SIGHUP storm, misbehaving Modbus devices (exception, garbage, wrong
# length, hang, NaN), CPU stress (stress-ng --cpu N if installed, else busy loops). Each case
# asserts its safe outcome; prints the table README.md shows.
# The cases live in tests/daemon/fault_campaign.rs (ignored in the normal `cargo test`).
set -euo pipefail
cd "$(dirname "$0")/../.."
exec cargo test --release --test daemon -- --ignored --nocapture --test-threads 1 fault_campaign::
