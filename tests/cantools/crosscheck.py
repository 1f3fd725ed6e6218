#!/usr/bin/env python3
"""cantools side of tests/bus/can_dbc_cantools.rs: an independent DBC codec to compare with.

    crosscheck.py encode DBC   -> JSON on stdout: frames cantools encoded from chosen values
    crosscheck.py decode DBC   <- JSON on stdin {"frames": [{"frame_id", "extended", "data"}]}
                               -> JSON on stdout: what cantools decodes from each frame

Floats travel as their IEEE-754 bit patterns (unsigned 64-bit integers) so that nothing is
lost in JSON. CRC bytes (signals with the AntisurgeRole attribute = Crc8) are computed with
crccheck's CRC-8/SAE-J1850 (a cantools dependency), independently of the Rust code, over the
4 little-endian bytes of the identifier and the payload without the CRC byte.

Exit status 3 with a message on stderr when cantools is missing.
"""

import json
import random
import struct
import sys

try:
    import cantools
    from crccheck.crc import Crc8SaeJ1850
except ImportError as exc:  # pragma: no cover - exercised by the Rust test's message
    sys.stderr.write(f"cannot import cantools ({exc}): pip install cantools\n")
    sys.exit(3)

ROLES = ["Data", "AliveCounter", "Crc8"]

# Realistic physical values for the skid (SI units), incl. negative ones.
TYPICAL = {
    "PSuction": 101325.4,
    "PDischarge": 252_000.6,
    "ShaftSpeed": 2513.27,
    "OrificeDp": -1234.26,  # reversed flow in deep surge
    "TSuction": 253.15,  # -20 degC: negative raw with the 273.15 offset
    "RecycleValvePosition": -0.0123,
    "ThrottlePosition": 0.61237,
    "ThrustPosition": -3.4567e-4,
    "DriveTorqueCmd": -12345.26,
    "RecycleValveCmd": 0.25001,
    "ThrottleCmd": 0.99995,
    "CloseCoupledValveCmd": -0.75004,
    "TipClearanceCmd": 1.23456e-4,
    "Mode": 3,
    "ActiveLaw": 7,
    "Faults": 0x105,
}


def fbits(x):
    return struct.unpack("<Q", struct.pack("<d", float(x)))[0]


def role(sig):
    attrs = sig.dbc.attributes if sig.dbc is not None else {}
    attr = attrs.get("AntisurgeRole")
    if attr is None:
        return "Data"
    value = attr.value
    if isinstance(value, int):
        return ROLES[value]
    return str(value)


def raw_range(sig):
    n = sig.length
    if sig.is_signed:
        return -(1 << (n - 1)), (1 << (n - 1)) - 1
    return 0, (1 << n) - 1


def frame_crc(msg, data, crc_sig):
    at = crc_sig.start // 8
    body = bytes(data[:at]) + bytes(data[at + 1 : msg.length])
    return Crc8SaeJ1850.calc(msg.frame_id.to_bytes(4, "little") + body)


def crc_signal(msg):
    for sig in msg.signals:
        if role(sig) == "Crc8":
            return sig
    return None


def decode_all(msg, data):
    raw = msg.decode(data, decode_choices=False, scaling=False)
    phys = msg.decode(data, decode_choices=False, scaling=True)
    return {k: int(v) for k, v in raw.items()}, {k: fbits(v) for k, v in phys.items()}


def raw_vectors(msg, rng):
    """Vectors of raw integer values: limits, small values, bit patterns, random."""
    out = []

    def vec(name, f):
        out.append((name, {s.name: f(s) for s in msg.signals}))

    vec("raw_min", lambda s: raw_range(s)[0])
    vec("raw_max", lambda s: raw_range(s)[1])
    vec("raw_zero", lambda s: 0)
    vec("raw_minus_one_or_one", lambda s: -1 if s.is_signed else 1)

    def pattern(s, p):
        v = p & ((1 << s.length) - 1)
        if s.is_signed and v >= 1 << (s.length - 1):
            v -= 1 << s.length
        return v

    vec("raw_0xAA", lambda s: pattern(s, 0xAAAA_AAAA_AAAA_AAAA))
    vec("raw_0x55", lambda s: pattern(s, 0x5555_5555_5555_5555))
    for i in range(4):
        vec(f"raw_random_{i}", lambda s: rng.randint(*raw_range(s)))
    return out


def phys_vectors(msg, rng):
    """Vectors of physical values: typical, random off-grid, exact half-LSB ties."""
    out = []

    def bounds(s):
        lo, hi = raw_range(s)
        lo, hi = max(lo + 1, -(1 << 50)), min(hi - 1, 1 << 50)
        a, b = lo * s.scale + s.offset, hi * s.scale + s.offset
        return min(a, b), max(a, b)

    def typical(s):
        if s.name in TYPICAL:
            return TYPICAL[s.name]
        a, b = bounds(s)
        return (a + b) / 2

    out.append(("phys_typical", {s.name: typical(s) for s in msg.signals}))
    for i in range(6):
        out.append((f"phys_random_{i}", {s.name: rng.uniform(*bounds(s)) for s in msg.signals}))
    # Half-LSB ties: exact in binary for power-of-two factors (0.5, 1, 3 is not, ...).
    ties = {}
    for s in msg.signals:
        lo, hi = raw_range(s)
        k = rng.randint(max(lo, -1000), min(hi, 1000) - 1)
        ties[s.name] = (k + 0.5) * s.scale + s.offset
    out.append(("phys_half_lsb", ties))
    return out


def encode_cmd(path):
    db = cantools.database.load_file(path)
    rng = random.Random(20240611)
    frames = []
    for msg in db.messages:
        crc_sig = crc_signal(msg)
        cases = [(n, v, False) for n, v in raw_vectors(msg, rng)]
        cases += [(n, v, True) for n, v in phys_vectors(msg, rng)]
        for name, values, scaling in cases:
            values = dict(values)
            if crc_sig is not None:
                values[crc_sig.name] = 0
                data = msg.encode(values, scaling=scaling, strict=False)
                values[crc_sig.name] = frame_crc(msg, data, crc_sig)
            data = msg.encode(values, scaling=scaling, strict=False)
            raw, phys = decode_all(msg, data)
            inputs = {}
            for s in msg.signals:
                v = values[s.name]
                if scaling and (crc_sig is None or s.name != crc_sig.name):
                    inputs[s.name] = {"phys": fbits(v)}
                else:
                    inputs[s.name] = {"raw": int(v)}
            frames.append(
                {
                    "message": msg.name,
                    "frame_id": msg.frame_id,
                    "extended": bool(msg.is_extended_frame),
                    "vector": name,
                    "inputs": inputs,
                    "data": bytes(data).hex(),
                    "raw": raw,
                    "phys": phys,
                }
            )
    json.dump({"cantools": cantools.__version__, "frames": frames}, sys.stdout)


def decode_cmd(path):
    db = cantools.database.load_file(path)
    request = json.load(sys.stdin)
    results = []
    for f in request["frames"]:
        data = bytes.fromhex(f["data"])
        msg = db.get_message_by_frame_id(f["frame_id"])
        if bool(msg.is_extended_frame) != bool(f["extended"]):
            raise SystemExit(f"id {f['frame_id']:#x}: extended flag mismatch")
        raw, phys = decode_all(msg, data)
        crc_sig = crc_signal(msg)
        crc_ok = None
        if crc_sig is not None:
            crc_ok = frame_crc(msg, data, crc_sig) == raw[crc_sig.name]
        results.append({"message": msg.name, "raw": raw, "phys": phys, "crc_ok": crc_ok})
    json.dump({"cantools": cantools.__version__, "frames": results}, sys.stdout)


def main(argv):
    if len(argv) != 3 or argv[1] not in ("encode", "decode"):
        sys.stderr.write(__doc__)
        return 2
    if argv[1] == "encode":
        encode_cmd(argv[2])
    else:
        decode_cmd(argv[2])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
