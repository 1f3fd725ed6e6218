#!/usr/bin/env bash
# Sparkplug B fleet benchmark (issue 26): `antisurge fleet-sim N` (N edge nodes in one
# process, each with its own simulated skid timeline and event log, publishing at 10 Hz with
# every change reported) against one Mosquitto, and the independent Python host
# (tests/sparkplug/host.py) checking every node's sequence, that 100 % of the QoS-1 events
# arrived, and the latency. Prints the figures the README quotes. Not a timed test.
#   .ci/sparkplug_fleet.sh [N=100] [DURATION_S=60]
# Needs: target/release/antisurge; mosquitto; python3 with paho-mqtt, protobuf, grpcio-tools.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
bin=$root/target/release/antisurge
n=${1:-100}
duration=${2:-60}
work=$(mktemp -d)
mosq_pid=""; host_pid=""
trap 'for p in $host_pid $mosq_pid; do kill $p 2>/dev/null || true; done; wait 2>/dev/null || true; rm -rf "$work"' EXIT
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
cd "$work"
printf 'listener %s 127.0.0.1\nallow_anonymous true\nmax_queued_messages 100000\n' "$port" >mosquitto.conf
mosquitto -c mosquitto.conf >mosquitto.log 2>&1 &
mosq_pid=$!
for _ in $(seq 50); do python3 -c "import socket; socket.create_connection(('127.0.0.1',$port),0.2)" 2>/dev/null && break; sleep 0.1; done
python3 "$root/tests/sparkplug/host.py" record --broker "127.0.0.1:$port" --group fleet --out rec.jsonl \
    --client-id fleet-host --ready host.ready >host.log 2>&1 &
host_pid=$!
for _ in $(seq 100); do [ -e host.ready ] && break; sleep 0.1; done
cpu() { awk '{print ($14 + $15) / 100}' "/proc/$1/stat"; }  # utime + stime, s (USER_HZ 100)
m0=$(cpu $mosq_pid); h0=$(cpu $host_pid)
echo "fleet: $n edge nodes x ${duration} s at 10 Hz against mosquitto on $port"
"$bin" fleet-sim "$n" --duration-s "$duration" --broker "127.0.0.1:$port" --dir "$work/fleet" | tee fleet.json
sleep 1
m1=$(cpu $mosq_pid); h1=$(cpu $host_pid)
kill -TERM $host_pid; wait $host_pid 2>/dev/null || true; host_pid=""
python3 "$root/tests/sparkplug/host.py" check --rec rec.jsonl --events-dir "$work/fleet" --all-events \
    --sessions 1 --brief | tee check.txt
python3 - "$duration" "$m0" "$m1" "$h0" "$h1" <<'PY'
import json, sys
d, m0, m1, h0, h1 = map(float, sys.argv[1:])
f = json.load(open("fleet.json"))
print(f"CPU over the run: edge nodes (fleet-sim process) {100 * f['cpu_s'] / f['wall_s']:.0f} % of one core "
      f"({1000 * f['cpu_s'] / f['wall_s'] / f['nodes']:.2f} ms/s per node); mosquitto {100 * (m1 - m0) / d:.0f} %; "
      f"Python host {100 * (h1 - h0) / d:.0f} %")
PY
