#!/usr/bin/env python3
"""Send a burst of malformed and unknown CAN frames: unknown ids, a known id with the wrong
length, and known ids with a bad CRC. Usage: malformed.py IFACE COUNT"""
import socket
import struct
import sys
import time

iface, count = sys.argv[1], int(sys.argv[2])
s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
s.bind((iface,))
def frame(can_id, data):
    return struct.pack("=IB3x8s", can_id, len(data), data.ljust(8, b"\0"))
sent = {"unknown_id": 0, "wrong_dlc": 0, "bad_crc": 0}
for i in range(count):
    s.send(frame(0x555 + (i % 7), bytes([i & 0xFF] * 8))); sent["unknown_id"] += 1
    s.send(frame(0x100, bytes([1, 2, 3]))); sent["wrong_dlc"] += 1       # PLANT_Pressures, 3 of 8 bytes
    s.send(frame(0x101, bytes([0xAA] * 8))); sent["bad_crc"] += 1         # PLANT_SpeedFlowTemp, CRC wrong
    time.sleep(0.001)
print("sent", sent)
