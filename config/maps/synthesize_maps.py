#!/usr/bin/env python3
"""Synthesize the tabulated compressor maps shipped in config/maps/.

Why synthesized: the seeds' compressor maps exist only as figures (seed 001 Fig. 2-2/2-4,
seed 002 Fig. A.1, seed 004's Kobe Steel rig), which are missing from the text extractions, and
no seed prints the fit coefficients (ERRATA.md: "the compressor-map fit coefficients of App. A
are not given"). Each map below is generated from a stated analytic speed-line shape whose
numbers come from what the seeds DO report (operating points, surge points, surge control line),
with fan-law speed scaling and a small deterministic "digitizing" error, then rounded like a
digitized table. antisurge never uses the generating shape: it fits the CSV points by least
squares (cubic per speed line, coefficients cubic in speed) exactly as a plant's own map data
would be fitted.

Speed-line shape (pressure ratio R versus flow q at speed N, s = N / N_ref):
    R(q, N) - 1 = s^2 * ( R_peak - 1 + a * (q/s - q_peak)^2 + d * (q/s - q_peak)^3 )
The peak (surge point) of each line is at q = q_peak * s. With a < 0 and d < 0 the line falls
steeply toward choke on the right, and the reverse-flow branch rises again for q < 0 (the
classical Greitzer/Moore-Greitzer shape); the local minimum -2a/(3d) lies at negative flow.

Run:  python3 config/maps/synthesize_maps.py   (rewrites the CSV files; deterministic)
"""
import math
import os

HERE = os.path.dirname(os.path.abspath(__file__))


def lcg(seed):
    """Deterministic pseudo-random numbers in [-1, 1] (no numpy needed)."""
    state = seed
    while True:
        state = (6364136223846793005 * state + 1442695040888963407) % (1 << 64)
        yield ((state >> 11) / float(1 << 53)) * 2.0 - 1.0


def write_map(name, header, comment, speeds, n_ref, r_peak, q_peak, a, d, q_lo, q_hi, npts,
              digitize_rel, decimals, seed):
    rnd = lcg(seed)
    lines = ["# " + c for c in comment.strip().splitlines()]
    lines.append("speed_rad_s,%s,pressure_ratio" % header)
    for n in speeds:
        s = n / n_ref
        for k in range(npts):
            x = q_lo + (q_hi - q_lo) * k / (npts - 1)  # speed-normalized flow q/s
            q = x * s
            dq = x - q_peak
            r = 1.0 + s * s * (r_peak - 1.0 + a * dq * dq + d * dq ** 3)
            r *= 1.0 + digitize_rel * next(rnd)
            if r <= 0.5:
                continue
            lines.append("%.1f,%.*f,%.4f" % (n, decimals, q, r))
    path = os.path.join(HERE, name)
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    print("wrote", path)


# Seed 002 (Kvangardsnes, natural-gas recycle system, App. A). Volumetric flow at suction
# (invariant coordinate, seed 002 sec. 2.3.1). The surge line is placed at
# q_SL = 0.5 sqrt(R - 1), 20 % in flow left of the printed surge control line
# q_SCL = c0 sqrt(R - 1), c0 = 0.6 (App. A), so that the SCL lies right of the surge line over
# the whole speed range (seed 002 eq. 4.2). N_ref = 1000 rad/s, peak R = 2.2.
write_map(
    "kvangardsnes2009_volumetric.csv", "volume_flow_m3_s",
    """Synthesized map for the seed 002 recycle benchmark (see synthesize_maps.py for why and how).
Flow: volumetric flow at compressor suction, m3/s. Surge line q = 0.5 sqrt(R-1), i.e. 20 %
left of seed 002's surge control line c0 = 0.6 (App. A).""",
    speeds=[700.0, 800.0, 900.0, 1000.0, 1100.0], n_ref=1000.0,
    r_peak=2.2, q_peak=0.5 * math.sqrt(1.2), a=-5.0, d=-4.0,
    q_lo=-0.25, q_hi=0.95, npts=13, digitize_rel=0.002, decimals=4, seed=2)

# Seed 001 (Hemchi & Tebba, Vortech S-trim supercharger). Mass flow. At 30 000 rpm
# (3140 rad/s, their speed setpoint) the surge point is placed at 0.2 kg/s, just left of the
# 0.23 kg/s their feedback-linearizing controller holds "near the surge line" (sec. 4.3.5), with
# peak pressure ratio 1.55 (their discharge/suction pressures 1.02-1.03e5 / 0.7e5 Pa give 1.46
# at 0.28-0.38 kg/s, sec. 3.5, 4.3.5).
write_map(
    "hemchi2016_vortech.csv", "mass_flow_kg_s",
    """Synthesized Vortech S-trim-like map for the seed 001 benchmark (see synthesize_maps.py).
Flow: mass flow, kg/s. Surge point 0.2 kg/s at pressure ratio 1.55 at 3140 rad/s (seed 001
sec. 4.3: 30 000 rpm).""",
    speeds=[2000.0, 2500.0, 3000.0, 3500.0, 4000.0], n_ref=3140.0,
    r_peak=1.55, q_peak=0.2, a=-1.5, d=-4.0,
    q_lo=-0.12, q_hi=0.56, npts=13, digitize_rel=0.002, decimals=4, seed=1)

# Seed 004 (Sanadgol & Maslen, Kobe Steel rig): 23 000 rpm (2408.6 rad/s), design pressure
# ratio 1.7 at the design flow 2500 m3/h (0.83 kg/s of air), open-loop surge near 0.5 kg/s.
# Peak R = 1.75 at 0.5 kg/s; the shape gives R = 1.70 at 0.83 kg/s.
write_map(
    "sanadgol2006_kobe.csv", "mass_flow_kg_s",
    """Synthesized map for the seed 004 Kobe Steel rig (see synthesize_maps.py).
Flow: mass flow, kg/s. At 23 000 rpm: surge point 0.5 kg/s at R = 1.75, design point
R = 1.70 at 0.83 kg/s (seed 004, "Compressor test rig").""",
    speeds=[1570.8, 1885.0, 2199.1, 2408.6, 2617.99], n_ref=2408.6,
    r_peak=1.75, q_peak=0.5, a=-0.36, d=-0.3,
    q_lo=-0.3, q_hi=1.5, npts=13, digitize_rel=0.002, decimals=4, seed=4)
