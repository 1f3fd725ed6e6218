#!/usr/bin/env bash
# Sparkplug B acceptance (issue 26), with real components: Debian's Mosquitto on a free port,
# the daemon with the embedded simulated plant as an edge node, and an independent Python
# host (tests/sparkplug/host.py: paho-mqtt + protobuf from a .proto written from the spec).
#   1. NBIRTH/DBIRTH decoded with datatypes, units and ranges; NDATA/DDATA followed through
#      the throttle closure; the deviation the host knows (the last value reported by
#      exception, deadband 0.25 % of its 200 % range) matches `antisurge status --json
#      --cycle N` at the cycle of the message, within 1 % (percentage points of the deviation);
#   2. a DCMD without commands enabled: refused and in the event log;
#   3. broker stopped 10 s during the closure, operator actions during the outage: their
#      events arrive after it returns, in order, none missing;
#   4. kill -9: NDEATH within the keep-alive (1.5 x keep_alive_s); restart: NBIRTH with
#      bdSeq + 1, seq 0, no sequence gap in any session;
#   5. commands enabled, wrong token: refused; right token: done.
# Needs: target/release/antisurge; mosquitto; python3 with paho-mqtt, protobuf, grpcio-tools.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
bin=$root/target/release/antisurge
host="python3 $root/tests/sparkplug/host.py"
work=$(mktemp -d)
mosq_pid=""; daemon_pid=""; host_pid=""
cleanup() {
    for p in $daemon_pid $host_pid $mosq_pid; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    if [ "${keep_work:-0}" = 1 ]; then echo "work directory kept: $work"; else rm -rf "$work"; fi
}
trap cleanup EXIT
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
ms() { python3 -c 'import time; print(int(time.time()*1000))'; }
port=$(free_port)
group=ci
node=skid-ci
keep_alive=2
cd "$work"

# persistence: the host's session (its subscription) survives the broker's restart, so what
# the node publishes before the host is back is queued for it (as on a production broker)
mkdir -p mosq && chmod 0755 "$work" && chmod 0777 mosq
cat >mosquitto.conf <<CONF
listener $port 127.0.0.1
allow_anonymous true
persistence true
persistence_location $work/mosq/
queue_qos0_messages true
CONF
start_broker() {
    mosquitto -c "$work/mosquitto.conf" >>mosquitto.log 2>&1 &
    mosq_pid=$!
    for _ in $(seq 50); do python3 -c "import socket; socket.create_connection(('127.0.0.1',$port),0.2)" 2>/dev/null && return; sleep 0.1; done
    echo "mosquitto did not start"; cat mosquitto.log; exit 1
}
start_broker

echo operator-t0ken >token && chmod 0640 token
status_cmd="$bin status --json --socket $work/status.sock --cycle {}"
$host record --broker "127.0.0.1:$port" --group $group --out rec.jsonl --ready host.ready \
    --status-cmd "$status_cmd" >host.log 2>&1 &
host_pid=$!
for _ in $(seq 100); do [ -e host.ready ] && break; sleep 0.1; done
[ -e host.ready ] || { echo "host did not connect"; cat host.log; exit 1; }

start_daemon() {  # $1: commands_enabled
    ANTISURGE_SPARKPLUG__ENABLED=true ANTISURGE_SPARKPLUG__BROKER="127.0.0.1:$port" \
    ANTISURGE_SPARKPLUG__GROUP_ID=$group ANTISURGE_SPARKPLUG__EDGE_NODE_ID=$node \
    ANTISURGE_SPARKPLUG__KEEP_ALIVE_S=$keep_alive ANTISURGE_SPARKPLUG__COMMANDS_ENABLED="$1" \
    ANTISURGE_SPARKPLUG__DEADBAND_PCT=0.25 \
    ANTISURGE_STATUS__SOCKET="$work/status.sock" ANTISURGE_STATUS__STATE_DIR="$work/state" \
    ANTISURGE_STATUS__OPERATOR_TOKEN_FILE="$work/token" ANTISURGE_STATUS__METRICS_LISTEN="" \
    ANTISURGE_STATUS__HMI_LISTEN="" ANTISURGE_EVENT_LOG__PATH="$work/events.jsonl" \
        "$bin" run --config "$root/config/antisurge.toml" >>daemon.log 2>&1 &
    daemon_pid=$!
}
births() { grep -c '"kind": "NBIRTH"' rec.jsonl 2>/dev/null || true; }
wait_births() {  # $1: how many NBIRTHs in total
    for _ in $(seq 150); do [ "$(births)" -ge "$1" ] && return; sleep 0.1; done
    echo "no NBIRTH number $1"; tail -20 daemon.log; exit 1
}
result_with() { for _ in $(seq 50); do grep -q "$1" rec.jsonl && return; sleep 0.1; done; echo "no command result with '$1'"; exit 1; }

echo "-- daemon 1 (commands refused): births, data through the closure"
start_daemon false
wait_births 1
sleep 2
$host cmd --broker "127.0.0.1:$port" --group $group --node $node --device compressor --words "manual 30"
result_with "commands are disabled"
grep -q 'Sparkplug DCMD `manual 30` refused: commands are disabled' events.jsonl \
    || { echo "the refused DCMD is not in the event log"; exit 1; }
echo "DCMD without commands enabled: refused and logged"

echo "-- broker stopped for 10 s during the closure; operator actions meanwhile"
out_a=$(ms)
kill -TERM $mosq_pid; wait $mosq_pid 2>/dev/null || true
"$bin" operate --socket "$work/status.sock" --token-file "$work/token" manual 40 >/dev/null
sleep 3
"$bin" operate --socket "$work/status.sock" --token-file "$work/token" auto >/dev/null
sleep 7
out_b=$(ms)
start_broker
wait_births 2
sleep 3

echo "-- kill -9; restart (commands enabled)"
kill_ms=$(ms)
kill -9 $daemon_pid; wait $daemon_pid 2>/dev/null || true
for _ in $(seq 100); do grep -q '"kind": "NDEATH"' rec.jsonl && break; sleep 0.1; done
start_daemon true
wait_births 3
sleep 6   # the second closure (t = 5..7 s of the scenario), compared with status
$host cmd --broker "127.0.0.1:$port" --group $group --node $node --device compressor --words "manual 30" --token wrong
result_with "wrong operator token"
$host cmd --broker "127.0.0.1:$port" --group $group --node $node --device compressor --words "ack" --token operator-t0ken
result_with "done: acknowledged"
$host rebirth --broker "127.0.0.1:$port" --group $group --node $node
wait_births 4
sleep 3
kill -TERM $daemon_pid; wait $daemon_pid 2>/dev/null || true
daemon_pid=""
sleep 0.5
kill -TERM $host_pid; wait $host_pid 2>/dev/null || true
host_pid=""

echo "-- the host's checks"
$host check --rec rec.jsonl --events-log events.jsonl --kill-ms "$kill_ms" --outage-ms "$out_a" "$out_b" \
    --keep-alive-s $keep_alive --min-compares 10 \
    --expect-result "commands are disabled" --expect-result "wrong operator token" \
    --expect-result "done: acknowledged" || { keep_work=1; tail -30 daemon.log; exit 1; }
echo "sparkplug: ok"
