#!/usr/bin/env python3
"""Sensor-frame-to-actuator-frame latency on the bus, from a `candump -t a` log.

For every controller command frame (CTRL_ActuatorCmd1, id 0x0A0) the latency is the time since
the newest plant sensor frame (PLANT_Pressures, id 0x100) before it: what the loop adds between
a sample on the wire and the command computed from it (the controller's wait for its next
cycle, its compute time, both bus transfers). Usage: latency.py CANDUMP_LOG [T_FROM_S T_TO_S]
(window in seconds after the first frame). Prints one JSON object, with the frames candump
reported dropped (a dropped sensor frame would inflate the figure).
"""
import json
import re
import sys

SENSOR, COMMAND = 0x100, 0x0A0
line_re = re.compile(r"\((\d+\.\d+)\)\s+\S+\s+([0-9A-Fa-f]+)[#\s]")


def percentile(v, q):
    v = sorted(v)
    return v[min(len(v) - 1, int(q * len(v)))]


def main():
    path = sys.argv[1]
    t_from = float(sys.argv[2]) if len(sys.argv) > 2 else 0.0
    t_to = float(sys.argv[3]) if len(sys.argv) > 3 else float("inf")
    t0 = None
    last_sensor = None
    lat_us = []
    drops = 0
    for line in open(path):
        if "DROPCOUNT" in line:
            # candump -d: "DROPCOUNT: dropped N CAN frame(s) on 'vcan0' socket (total drops M)"
            nums = re.findall(r"total drops (\d+)", line)
            drops = max(drops, int(nums[0])) if nums else drops + 1
            continue
        m = line_re.search(line)
        if not m:
            continue
        t, can_id = float(m.group(1)), int(m.group(2), 16)
        t0 = t if t0 is None else t0
        if can_id == SENSOR:
            last_sensor = t
        elif can_id == COMMAND and last_sensor is not None and t_from <= t - t0 <= t_to:
            lat_us.append((t - last_sensor) * 1e6)
    if not lat_us:
        print(json.dumps({"frames": 0, "dropped": drops}))
        return 1
    print(json.dumps({
        "frames": len(lat_us),
        "dropped": drops,
        "p50_us": percentile(lat_us, 0.5),
        "p99_us": percentile(lat_us, 0.99),
        "max_us": max(lat_us),
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
