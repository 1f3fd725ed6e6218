#!/usr/bin/env python3
"""Send a burst of malformed and unknown CAN frames: unknown ids, a known id with the wrong
length, and known ids with a bad CRC. Usage: malformed.py IFACE COUNT [START_EPOCH_S]

With START_EPOCH_S (a wall-clock time, `date +%s.%N`), the socket is opened at once and the
burst starts at that time: interpreter start-up (seconds in an emulated VM) cannot delay it."""
import socket
import struct
import sys
import time

iface, count = sys.argv[1], int(sys.argv[2])
start = float(sys.argv[3]) if len(sys.argv) > 3 else time.time()
s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
s.bind((iface,))
s.settimeout(2.0)  # a send that cannot go out within 2 s fails the burst instead of hanging it
late = time.time() - start
if late > 0:
    print(f"started {late:.2f} s after the requested time")
time.sleep(max(0.0, start - time.time()))
t0 = time.time()
def frame(can_id, data):
    return struct.pack("=IB3x8s", can_id, len(data), data.ljust(8, b"\0"))
sent = {"unknown_id": 0, "wrong_dlc": 0, "bad_crc": 0}
try:
    for i in range(count):
        s.send(frame(0x555 + (i % 7), bytes([i & 0xFF] * 8))); sent["unknown_id"] += 1
        s.send(frame(0x100, bytes([1, 2, 3]))); sent["wrong_dlc"] += 1       # PLANT_Pressures, 3 of 8 bytes
        s.send(frame(0x101, bytes([0xAA] * 8))); sent["bad_crc"] += 1         # PLANT_SpeedFlowTemp, CRC wrong
        time.sleep(0.001)
except OSError as e:
    print(f"send failed after {sum(sent.values())} frames: {e!r}")
print(f"burst of {sum(sent.values())} frames took {time.time() - t0:.2f} s")
print("sent", sent, flush=True)
