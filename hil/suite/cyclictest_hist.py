#!/usr/bin/env python3
"""Wake-up latency percentiles from the output of `cyclictest -q -h N` (one thread).

Usage: cyclictest_hist.py FILE   prints {"p50": µs, "p99": µs, "max": µs, "samples": n}.
Imported by hil/suite/check.py; run by benches/rt_figures.sh.
"""
import json
import sys


def stats(text):
    """p50, p99, max (µs) and the sample count of a cyclictest histogram."""
    hist, max_us = [], None
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0].isdigit() and parts[1].isdigit():
            hist.append((int(parts[0]), int(parts[1])))
        elif line.startswith("# Max Latencies"):
            max_us = int(line.split(":")[1].split()[0])
    n = sum(k for _, k in hist)

    def quantile(q):
        acc = 0
        for us, k in hist:
            acc += k
            if acc >= q * n:
                return us
        return None

    return {"p50": quantile(0.5), "p99": quantile(0.99), "max": max_us, "samples": n}


if __name__ == "__main__":
    with open(sys.argv[1]) as f:
        print(json.dumps(stats(f.read())))
