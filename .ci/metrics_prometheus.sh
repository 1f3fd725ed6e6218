#!/usr/bin/env bash
# Metrics acceptance: the daemon's exposition passes `promtool check metrics`, and a real
# Prometheus (Debian package) scrapes it and answers a query for the deviation, which must
# match `antisurge status --json` within 1 % (of the control-line flow, the deviation's unit).
# Needs: target/release/antisurge built; apt-get install prometheus (promtool, prometheus).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=$PWD/target/release/antisurge
work=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
mport=$(free_port); pport=$(free_port)

cd "$work"
ANTISURGE_STATUS__METRICS_LISTEN="127.0.0.1:$mport" ANTISURGE_STATUS__SOCKET="$work/status.sock" \
ANTISURGE_STATUS__STATE_DIR="$work/state" ANTISURGE_EVENT_LOG__PATH="$work/events.jsonl" \
    "$bin" run --config "$OLDPWD/config/antisurge.toml" >daemon.log 2>&1 &
for _ in $(seq 50); do curl -sf "http://127.0.0.1:$mport/metrics" >/dev/null && break; sleep 0.2; done

curl -sf "http://127.0.0.1:$mport/metrics" >metrics.txt
promtool check metrics <metrics.txt
echo "promtool check metrics: ok ($(grep -c '^antisurge_' metrics.txt) samples)"

cat >prometheus.yml <<YML
global:
  scrape_interval: 1s
scrape_configs:
  - job_name: antisurge
    static_configs:
      - targets: ["127.0.0.1:$mport"]
YML
prometheus --config.file=prometheus.yml --storage.tsdb.path="$work/tsdb" \
    --web.listen-address="127.0.0.1:$pport" >prometheus.log 2>&1 &
value=""
for _ in $(seq 60); do
    sleep 1
    value=$(curl -sf "http://127.0.0.1:$pport/api/v1/query?query=antisurge_deviation_ratio" \
        | python3 -c 'import json,sys; r=json.load(sys.stdin)["data"]["result"]; print(r[0]["value"][1] if r else "")' || true)
    [ -n "$value" ] && break
done
[ -n "$value" ] || { echo "Prometheus returned no deviation"; tail -20 prometheus.log; exit 1; }
status=$("$bin" status --json --socket "$work/status.sock" | python3 -c 'import json,sys; print(json.load(sys.stdin)["deviation_pct"])')
echo "Prometheus: antisurge_deviation_ratio = $value; antisurge status: deviation_pct = $status"
python3 - "$value" "$status" <<'PY'
import sys
prom, status = float(sys.argv[1]) * 100, float(sys.argv[2])
assert abs(prom - status) <= 1.0, f"deviation {prom} % (Prometheus) vs {status} % (status)"
PY
echo "metrics + Prometheus: ok"
