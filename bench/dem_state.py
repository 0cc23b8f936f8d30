"""`/dem/state` records of a `coupler run` recording, decoded (the layout
and the decoder of docs/recording.md, "/dem/state"): the grains by id,
which `/dem/particles` cannot give (its points are in the solver's
storage order, re-sorted every `dem.sort_interval` steps).

    from dem_state import states
    for s in states(run_dir):   # s["time"], s["by_id"][id] = (position, velocity)
"""
import struct
from mcap.reader import make_reader


def decode_state(b):
    pos = 0

    def varint():
        nonlocal pos
        x = b[pos]
        pos += 1
        if x < 251:
            return x
        n = {251: 2, 252: 4, 253: 8}[x]
        v = int.from_bytes(b[pos:pos + n], "little")
        pos += n
        return v

    def f64s(n):
        nonlocal pos
        v = struct.unpack_from(f"<{n}d", b, pos)
        pos += 8 * n
        return v

    s = {"version": varint(), "time": f64s(1)[0], "step": varint()}
    for name, width in [("pos", 3), ("vel", 3), ("omega", 3), ("force", 3), ("torque", 3), ("radius", 1), ("mass", 1)]:
        n = varint()
        flat = f64s(n * width)
        s[name] = list(flat) if width == 1 else [flat[k * width:(k + 1) * width] for k in range(n)]
    s["ids"] = [varint() for _ in range(varint())]
    return s


def states(run):
    """Every `/dem/state` of RUN_DIR/run.mcap in time order, each with
    `by_id`: id -> (position, velocity, radius)."""
    out = []
    with open(f"{run}/run.mcap", "rb") as f:
        for _, _, msg in make_reader(f).iter_messages(topics=["/dem/state"]):
            s = decode_state(msg.data)
            s["by_id"] = {i: (p, v, r) for i, p, v, r in zip(s["ids"], s["pos"], s["vel"], s["radius"])}
            out.append(s)
    out.sort(key=lambda s: s["time"])
    return out
