#!/usr/bin/env python3
"""An independent Sparkplug B host for the edge node's end-to-end test (paho-mqtt + protobuf).

The payload classes are generated at start from sparkplug_b.proto (written from the
specification, not from the Rust side) with grpc_tools' protoc.

  host.py record --broker H:P --group G --out REC [--status-cmd 'antisurge status ... --cycle {}']
      subscribe to spBv1.0/G/#, write every message decoded (one JSON object a line); with
      --status-cmd, compare the compressor's Deviation with `antisurge status` at the same
      control cycle now and then ("compare" lines).
  host.py cmd --broker H:P --group G --node N [--device D] --words 'manual 30' [--token T]
  host.py rebirth --broker H:P --group G --node N
  host.py check --rec REC [--events-log F] [--kill-ms T ...] [--outage-ms A B] [--keep-alive-s S]
      check every sequence (see check()); prints a summary, exits 1 on a failure.
"""
import argparse
import importlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def load_proto():
    out = tempfile.mkdtemp(prefix="spb_")
    from grpc_tools import protoc  # noqa: E402
    import grpc_tools
    inc = os.path.join(os.path.dirname(grpc_tools.__file__), "_proto")
    rc = protoc.main(["protoc", f"-I{HERE}", f"-I{inc}", f"--python_out={out}", "sparkplug_b.proto"])
    if rc != 0:
        sys.exit(f"protoc failed ({rc})")
    sys.path.insert(0, out)
    return importlib.import_module("sparkplug_b_pb2")


def now_ms():
    return int(time.time() * 1000)


def split_topic(topic):
    p = topic.split("/")
    if len(p) < 4 or p[0] != "spBv1.0":
        return None
    return {"group": p[1], "kind": p[2], "node": p[3], "device": p[4] if len(p) > 4 else None}


def value_of(m):
    which = m.WhichOneof("value")
    if m.is_null or which is None:
        return None
    return getattr(m, which)


def props_of(m):
    if not m.HasField("properties"):
        return None
    out = {}
    for k, v in zip(m.properties.keys, m.properties.values):
        w = v.WhichOneof("value")
        out[k] = getattr(v, w) if w else None
    return out


def decode(pb, topic, payload):
    t = split_topic(topic)
    if t is None:
        return None
    rec = dict(t, topic=topic, recv_ms=now_ms())
    if t["kind"] == "STATE":
        return None
    p = pb.Payload()
    p.ParseFromString(payload)
    rec["seq"] = p.seq if p.HasField("seq") else None
    rec["timestamp"] = p.timestamp if p.HasField("timestamp") else None
    rec["metrics"] = [
        {
            "name": m.name,
            "datatype": m.datatype if m.HasField("datatype") else None,
            "value": value_of(m),
            "is_null": m.is_null,
            "historical": m.is_historical,
            "timestamp": m.timestamp if m.HasField("timestamp") else None,
            "properties": props_of(m),
        }
        for m in p.metrics
    ]
    return rec


def connect(args, client_id, clean=True):
    import paho.mqtt.client as mqtt
    host, port = args.broker.rsplit(":", 1)
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=clean)
    c.connect(host, int(port), keepalive=10)
    return c


def record(args):
    import paho.mqtt.client as mqtt
    pb = load_proto()
    out = open(args.out, "a", buffering=1)
    lock = threading.Lock()
    last_compare = [0.0]
    known = {}

    def write(obj):
        with lock:
            out.write(json.dumps(obj) + "\n")

    def compare(cycle, deviation, node):
        cmd = args.status_cmd.replace("{}", str(cycle))
        try:
            r = subprocess.run(cmd, shell=True, capture_output=True, text=True, timeout=5)
            s = json.loads(r.stdout)
        except Exception as e:  # a restart in progress: no answer
            write({"kind": "compare_error", "node": node, "cycle": cycle, "error": str(e)})
            return
        if "error" in s:
            write({"kind": "compare_error", "node": node, "cycle": cycle, "error": s["error"]})
            return
        write({"kind": "compare", "node": node, "cycle": cycle, "host": deviation,
               "status": s.get("deviation_pct"), "status_cycle": s.get("cycle")})

    def on_connect(c, userdata, flags, reason, props):
        c.subscribe(f"spBv1.0/{args.group}/#", qos=1)
        write({"kind": "host_connected", "recv_ms": now_ms(), "session_present": bool(flags.session_present)})
        if args.ready:
            open(args.ready, "w").close()

    def on_message(c, userdata, msg):
        rec = decode(pb, msg.topic, msg.payload)
        if rec is None:
            return
        write(rec)
        if rec["device"] != "compressor" or rec["kind"] not in ("DBIRTH", "DDATA"):
            return
        # what the host knows: the last reported value (report by exception), at the cycle
        # of the message (every compressor DDATA carries its cycle)
        vals = {m["name"]: m["value"] for m in rec["metrics"]}
        if "Deviation" in vals:
            known[rec["node"]] = vals["Deviation"]
        dev = known.get(rec["node"])
        if args.status_cmd and rec["kind"] == "DDATA" and dev is not None and "Cycle" in vals \
                and time.time() - last_compare[0] > args.compare_every_s:
            last_compare[0] = time.time()
            threading.Thread(target=compare, args=(vals["Cycle"], dev, rec["node"]),
                             daemon=True).start()

    host, port = args.broker.rsplit(":", 1)
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=args.client_id, clean_session=False)
    c.on_connect = on_connect
    c.on_message = on_message
    c.reconnect_delay_set(min_delay=1, max_delay=1)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    while not stop.is_set():
        try:
            c.connect(host, int(port), keepalive=5)
            break
        except OSError:
            time.sleep(0.2)
    c.loop_start()
    stop.wait()
    c.loop_stop()
    out.close()


def metric(name, kind, value):
    return name, kind, value


def send_cmd(args, metrics):
    pb = load_proto()
    p = pb.Payload()
    p.timestamp = now_ms()
    for name, kind, value in metrics:
        m = p.metrics.add()
        m.name = name
        m.timestamp = p.timestamp
        if kind == "bool":
            m.datatype = 11
            m.boolean_value = value
        else:
            m.datatype = 12
            m.string_value = value
    if args.device:
        topic = f"spBv1.0/{args.group}/DCMD/{args.node}/{args.device}"
    else:
        topic = f"spBv1.0/{args.group}/NCMD/{args.node}"
    c = connect(args, f"spb-cmd-{os.getpid()}")
    c.loop_start()
    info = c.publish(topic, p.SerializeToString(), qos=0)
    info.wait_for_publish(5)
    c.disconnect()
    c.loop_stop()
    print(f"sent {topic}: {[m[0] for m in metrics]}")


def cmd(args):
    ms = [metric("Operator/Command", "str", args.words)]
    if args.token is not None:
        ms.insert(0, metric("Operator/Token", "str", args.token))
    send_cmd(args, ms)


def rebirth(args):
    args.device = None
    send_cmd(args, [metric("Node Control/Rebirth", "bool", True)])


class Failures(list):
    def expect(self, ok, what):
        if not ok:
            self.append(what)
        return ok


def check(args):
    recs = [json.loads(l) for l in open(args.rec) if l.strip()]
    f = Failures()
    summary = {}
    nodes = sorted({r["node"] for r in recs if r.get("kind") in ("NBIRTH", "NDATA", "DBIRTH", "DDATA", "NDEATH")})
    f.expect(nodes, "no edge node seen")
    births_needing_props = {"Deviation": "%", "Valve/Command": "%", "Shaft Speed": "rad/s"}
    for node in nodes:
        s = {"sessions": 0, "messages": 0, "gaps": 0, "ndeath": 0, "stale_ndeath": 0, "events": []}
        bd = None        # bdSeq of the session in force
        last_bd = None   # bdSeq of the last NBIRTH
        expect_seq = None
        born_devices = set()
        for r in recs:
            if r.get("node") != node or r.get("kind") not in ("NBIRTH", "NDATA", "DBIRTH", "DDATA", "NDEATH", "DDEATH"):
                continue
            k = r["kind"]
            names = {m["name"]: m for m in r["metrics"]}
            if k == "NBIRTH":
                s["sessions"] += 1
                f.expect(r["seq"] == 0, f"{node}: NBIRTH seq {r['seq']} (want 0)")
                b = names.get("bdSeq", {}).get("value")
                f.expect(b is not None, f"{node}: NBIRTH without bdSeq")
                if last_bd is not None and b is not None:
                    f.expect(b == (last_bd + 1) % 256 or b == last_bd,
                             f"{node}: NBIRTH bdSeq {b} after {last_bd} (want +1, or the same on a rebirth)")
                bd = last_bd = b
                expect_seq = 1
                born_devices = set()
                f.expect(all(m["datatype"] for m in r["metrics"]), f"{node}: NBIRTH metric without datatype")
                continue
            if k == "NDEATH":
                b = names.get("bdSeq", {}).get("value")
                if bd is not None and b == bd:
                    s["ndeath"] += 1
                    s.setdefault("ndeath_ms", []).append(r["recv_ms"])
                    bd = None
                    expect_seq = None
                else:
                    s["stale_ndeath"] += 1  # the will of an older session (the host ignores it)
                continue
            s["messages"] += 1
            if not f.expect(expect_seq is not None, f"{node}: {k} seq {r['seq']} outside a session"):
                continue
            if r["seq"] != expect_seq:
                s["gaps"] += 1
                f.append(f"{node}: {k} seq {r['seq']}, want {expect_seq} (gap)")
            expect_seq = (r["seq"] + 1) % 256
            if k == "DBIRTH":
                born_devices.add(r["device"])
                f.expect(all(m["datatype"] for m in r["metrics"]), f"{node}/{r['device']}: DBIRTH metric without datatype")
                if r["device"] == "compressor":
                    for name, unit in births_needing_props.items():
                        p = (names.get(name) or {}).get("properties") or {}
                        f.expect(p.get("engUnit") == unit and "engLow" in p and "engHigh" in p,
                                 f"{node}: DBIRTH {name} properties {p}")
            if k == "DDATA":
                f.expect(r["device"] in born_devices, f"{node}: DDATA of {r['device']} before its DBIRTH")
            if k == "NDATA" and "Events/Seq" in names:
                s["events"].append((names["Events/Seq"]["value"], r["recv_ms"], names["Events/Seq"]["historical"]))
        summary[node] = s
    # latency: publish (payload timestamp, the node's clock) to reception (same machine)
    lat = sorted(r["recv_ms"] - r["timestamp"] for r in recs
                 if r.get("kind") in ("NDATA", "DDATA") and r.get("timestamp"))
    if lat:
        summary["latency_ms"] = {"n": len(lat), "p50": lat[len(lat) // 2],
                                 "p99": lat[min(len(lat) - 1, int(len(lat) * 0.99))], "max": lat[-1]}
    # events: in order, none missing, against the event log(s)
    logs = {}
    if args.events_log:
        log = [json.loads(l) for l in open(args.events_log) if l.strip()]
        logs = {node: log for node in nodes}
    if args.events_dir:
        for node in nodes:
            path = os.path.join(args.events_dir, node, "events.jsonl")
            logs[node] = [json.loads(l) for l in open(path) if l.strip()]
    if logs:
        for node in nodes:
            log = logs[node]
            got, seen = [], set()
            for seq, t, hist in summary[node]["events"]:
                if seq not in seen:
                    seen.add(seq)
                    got.append(seq)
            f.expect(got == sorted(got), f"{node}: events out of order {got[:20]}")
            if args.all_events:
                want = [e["seq"] for e in log]
                missing = sorted(set(want) - seen)
                f.expect(not missing, f"{node}: events missing {missing[:20]} of {len(want)}")
                summary[node]["events_written"] = len(want)
            elif got:
                want = [e["seq"] for e in log if got[0] <= e["seq"] <= got[-1]]
                missing = sorted(set(want) - seen)
                f.expect(not missing, f"{node}: events missing {missing[:20]}")
            summary[node]["events_received"] = len(got)
            summary[node]["event_duplicates"] = len(summary[node]["events"]) - len(got)
            if args.outage_ms:
                a, b = args.outage_ms
                during = [e["seq"] for e in log if a <= ts_ms(e["ts"]) <= b]
                f.expect(during, "no event during the outage (the test writes some)")
                missing = [q for q in during if q not in seen]
                f.expect(not missing, f"{node}: outage events missing {missing}")
                order = [q for q in got if q in during]
                f.expect(order == during, f"{node}: outage events out of order {order} vs {during}")
                late = [t for q, t, h in summary[node]["events"] if q in during]
                f.expect(all(t >= b for t in late), f"{node}: outage events received before the broker returned?")
                hist = [h for q, t, h in summary[node]["events"] if q in during]
                summary[node]["outage_events"] = len(during)
                summary[node]["outage_events_historical"] = sum(1 for h in hist if h)
    for kill in args.kill_ms or []:
        for node in nodes:
            after = [t for t in summary[node].get("ndeath_ms", []) if t >= kill]
            if f.expect(after, f"{node}: no NDEATH after the kill at {kill}"):
                delay = (after[0] - kill) / 1000
                summary[node].setdefault("ndeath_after_kill_s", []).append(delay)
                f.expect(delay <= 1.5 * args.keep_alive_s + 1.0,
                         f"{node}: NDEATH {delay:.1f} s after the kill (keep-alive {args.keep_alive_s} s)")
    cmp = [r for r in recs if r.get("kind") == "compare"]
    if args.min_compares:
        f.expect(len(cmp) >= args.min_compares, f"only {len(cmp)} deviation comparisons")
        worst = 0.0
        for r in cmp:
            if r["host"] is None or r["status"] is None:
                f.append(f"cycle {r['cycle']}: deviation host {r['host']} status {r['status']}")
                continue
            d = abs(r["host"] - r["status"])
            worst = max(worst, d)
            f.expect(d <= 1.0, f"cycle {r['cycle']}: deviation {r['host']} (host) vs {r['status']} (status)")
            f.expect(r["status_cycle"] == r["cycle"], f"status answered cycle {r['status_cycle']} for {r['cycle']}")
        devs = [r["host"] for r in cmp if r["host"] is not None]
        summary["deviation_compares"] = {"n": len(cmp), "worst_abs_diff_pct_points": worst,
                                         "min": min(devs) if devs else None, "max": max(devs) if devs else None}
    for node in nodes:
        summary[node].pop("events", None)
        summary[node].pop("ndeath_ms", None)
        if args.sessions is not None:
            f.expect(summary[node]["sessions"] == args.sessions,
                     f"{node}: {summary[node]['sessions']} sessions, want {args.sessions}")
    if args.brief:
        per = [summary.pop(n) for n in nodes]
        summary["nodes"] = len(nodes)
        for k in ("sessions", "messages", "gaps", "ndeath", "events_received", "events_written", "event_duplicates"):
            summary[k] = sum(p.get(k, 0) for p in per)
    results = [r for r in recs if r.get("kind") == "NDATA" and any(m["name"] == "Operator/Last Result" for m in r["metrics"])]
    summary["command_results"] = [m["value"] for r in results for m in r["metrics"] if m["name"] == "Operator/Last Result"]
    for want in args.expect_result or []:
        f.expect(any(want in x for x in summary["command_results"]), f"no command result containing `{want}`")
    print(json.dumps(summary, indent=1, default=str))
    if f:
        print("FAILED:\n  " + "\n  ".join(f[:50]))
        sys.exit(1)
    print("sparkplug host: every check passed")


def ts_ms(ts):
    from datetime import datetime
    return int(datetime.fromisoformat(ts.replace("Z", "+00:00")).timestamp() * 1000)


def main():
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="what", required=True)
    r = sub.add_parser("record")
    r.add_argument("--broker", required=True)
    r.add_argument("--group", required=True)
    r.add_argument("--out", required=True)
    r.add_argument("--client-id", default="spb-test-host")
    r.add_argument("--status-cmd")
    r.add_argument("--compare-every-s", type=float, default=0.3)
    r.add_argument("--ready")
    for name in ("cmd", "rebirth"):
        c = sub.add_parser(name)
        c.add_argument("--broker", required=True)
        c.add_argument("--group", required=True)
        c.add_argument("--node", required=True)
        if name == "cmd":
            c.add_argument("--device")
            c.add_argument("--words", required=True)
            c.add_argument("--token")
    k = sub.add_parser("check")
    k.add_argument("--rec", required=True)
    k.add_argument("--events-log")
    k.add_argument("--kill-ms", type=int, action="append")
    k.add_argument("--outage-ms", type=int, nargs=2)
    k.add_argument("--keep-alive-s", type=float, default=5)
    k.add_argument("--min-compares", type=int, default=0)
    k.add_argument("--expect-result", action="append")
    k.add_argument("--events-dir", help="per-node event logs: DIR/<node>/events.jsonl")
    k.add_argument("--all-events", action="store_true", help="every event of the log(s) must arrive")
    k.add_argument("--sessions", type=int, help="NBIRTHs each node must have")
    k.add_argument("--brief", action="store_true", help="totals instead of one summary per node")
    a = ap.parse_args()
    {"record": record, "cmd": cmd, "rebirth": rebirth, "check": check}[a.what](a)


if __name__ == "__main__":
    main()
