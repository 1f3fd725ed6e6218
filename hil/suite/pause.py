#!/usr/bin/env python3
"""Stop a process for a few milliseconds, several times: what a busy host does to the plant.

Usage: pause.py PID START_S COUNT INTERVAL_S PAUSE_S

Waits START_S, then COUNT times: SIGSTOP, PAUSE_S, SIGCONT, INTERVAL_S. Prints each pause as
measured on the monotonic clock. (A shell's `kill; sleep; kill` forks `sleep`: in the VM that
stopped the plant for about 64 ms, far beyond a host's hiccup and beyond what the skid bus's
4-bit alive counter can tell from lost frames: 8 periods.)
"""
import os
import signal
import sys
import time

pid, start_s, count, interval_s, pause_s = (int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]),
                                            float(sys.argv[4]), float(sys.argv[5]))
time.sleep(start_s)
for k in range(1, count + 1):
    t0 = time.monotonic()
    os.kill(pid, signal.SIGSTOP)
    time.sleep(pause_s)
    os.kill(pid, signal.SIGCONT)
    t1 = time.monotonic()
    print(f"pause {k}: plant stopped {1000 * (t1 - t0):.2f} ms", flush=True)
    time.sleep(interval_s)
