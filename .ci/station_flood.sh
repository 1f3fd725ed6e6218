#!/usr/bin/env bash
# Issue 24 benchmark: a minute of GET /api/events at 200 requests/s against the daemon on a
# Modbus TCP link (bus I/O threads at SCHED_FIFO where granted), beside an unflooded minute
# in the same run. Asserts that no request was handled on a real-time thread and that the
# link's poll period stayed within the configured period + 20 %; prints the control
# overruns, wake-up jitter and link period of both minutes (README.md "Benchmarks" records
# them). The plain `cargo test` runs the same test with 10-s windows.
set -euo pipefail
cd "$(dirname "$0")/.."
ANTISURGE_FLOOD_S=${ANTISURGE_FLOOD_S:-60} cargo test --release --test operator \
    station_attack::an_event_list_flood -- --nocapture
