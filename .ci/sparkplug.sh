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
#   5. commands enabled, wrong token: refused; right token: done;
#   6. TLS (a CA file) and broker credentials (a password file with the token file's rules):
#      check-config refuses a world-readable one; the node publishes over TLS with them.
# Needs: target/release/antisurge; mosquitto; python3 with paho-mqtt, protobuf, grpcio-tools.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
bin=$root/target/release/antisurge
host="python3 $root/tests/sparkplug/host.py"
work=$(mktemp -d)
mosq_pid=""; daemon_pid=""; host_pid=""; tls_pid=""
cleanup() {
    for p in $daemon_pid $host_pid $mosq_pid $tls_pid; do kill "$p" 2>/dev/null || true; done
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

broker="127.0.0.1:$port"
extra=()
start_daemon() {  # $1: commands_enabled; $broker, and ${extra[@]} more settings
    env "${extra[@]}" ANTISURGE_SPARKPLUG__ENABLED=true ANTISURGE_SPARKPLUG__BROKER="$broker" \
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

echo "-- TLS and broker credentials (the password file has the token file's rules)"
tport=$(free_port)
openssl req -x509 -newkey rsa:2048 -nodes -days 2 -subj /CN=test-ca -keyout ca.key -out ca.crt 2>/dev/null
openssl req -newkey rsa:2048 -nodes -subj /CN=127.0.0.1 -keyout srv.key -out srv.csr 2>/dev/null
printf 'subjectAltName=IP:127.0.0.1\n' >san.ext
openssl x509 -req -in srv.csr -CA ca.crt -CAkey ca.key -CAcreateserial -days 2 -extfile san.ext -out srv.crt 2>/dev/null
chmod 0644 srv.key  # the test broker drops to its own user
: >passwd && mosquitto_passwd -b passwd skid mqtt-s3cret && chmod 0644 passwd
echo mqtt-s3cret >mqtt.password && chmod 0644 mqtt.password
tls_env() {
    env ANTISURGE_SPARKPLUG__BROKER="127.0.0.1:$tport" ANTISURGE_SPARKPLUG__CA_FILE="$work/ca.crt" \
        ANTISURGE_SPARKPLUG__USERNAME=skid ANTISURGE_SPARKPLUG__PASSWORD_FILE="$work/mqtt.password" "$@"
}
if tls_env ANTISURGE_SPARKPLUG__ENABLED=true "$bin" check-config "$root/config/antisurge.toml" >check.txt 2>&1; then
    echo "check-config accepted a password file readable by everyone"; exit 1
fi
grep -q "sparkplug.password_file" check.txt || { echo "check-config did not name sparkplug.password_file"; cat check.txt; exit 1; }
chmod 0640 mqtt.password
printf 'listener %s 127.0.0.1\ncafile %s/ca.crt\ncertfile %s/srv.crt\nkeyfile %s/srv.key\nallow_anonymous false\npassword_file %s/passwd\n' \
    "$tport" "$work" "$work" "$work" "$work" >tls.conf
mosquitto -c tls.conf >mosquitto-tls.log 2>&1 &
tls_pid=$!
sleep 0.5
broker="127.0.0.1:$tport"
extra=(ANTISURGE_SPARKPLUG__CA_FILE="$work/ca.crt" ANTISURGE_SPARKPLUG__USERNAME=skid
       ANTISURGE_SPARKPLUG__PASSWORD_FILE="$work/mqtt.password")
start_daemon false
python3 - "$tport" "$work/ca.crt" $group $node <<'PY'
import sys, threading, paho.mqtt.client as mqtt
port, ca, group, node = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
got = threading.Event()
c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="tls-host")
c.tls_set(ca_certs=ca)
c.username_pw_set("skid", "mqtt-s3cret")
c.on_connect = lambda c, u, f, r, p: c.subscribe(f"spBv1.0/{group}/#", qos=1)
c.on_message = lambda c, u, m: got.set() if m.topic.startswith(f"spBv1.0/{group}/DDATA/{node}") else None
c.connect("127.0.0.1", port)
c.loop_start()
ok = got.wait(20)
c.loop_stop()
sys.exit(0 if ok else "no DDATA over TLS with credentials")
PY
grep -q "connected to 127.0.0.1:$tport" daemon.log || { echo "the node did not connect over TLS"; exit 1; }
echo "TLS + credentials: the node's DDATA received over TLS; a world-readable password file refused by check-config"
kill -TERM $daemon_pid; wait $daemon_pid 2>/dev/null || true
daemon_pid=""
kill $tls_pid 2>/dev/null || true

echo "-- the host's checks"
$host check --rec rec.jsonl --events-log events.jsonl --kill-ms "$kill_ms" --outage-ms "$out_a" "$out_b" \
    --keep-alive-s $keep_alive --min-compares 10 \
    --expect-result "commands are disabled" --expect-result "wrong operator token" \
    --expect-result "done: acknowledged" || { keep_work=1; tail -30 daemon.log; exit 1; }
echo "sparkplug: ok"
