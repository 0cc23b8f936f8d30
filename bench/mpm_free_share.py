"""Share of an MPM run's pore water (by the liquid points' volumes) that the
free-surface rule holds at p = 0 (drained or part-empty elements), at
t/t_ref = 0.5, 1, 2, 4: of all the water, and of the water beyond the gate
(x > L0), the flowing sheet. Reads the /mpm/liquid clouds (field 5: free).

usage: python3 bench/mpm_free_share.py RUN_DIR...
(docs/mpm.md, "Open points" 5; needs `pip install mcap mcap-protobuf-support`)
"""
import struct, sys, tomllib
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
for run in sys.argv[1:]:
    scene = tomllib.load(open(f"{run}/scene.toml", "rb"))
    g = -scene["domain"]["gravity"][2]; h0 = scene["analysis"]["column_height"]; L0 = scene["analysis"]["column_length"]
    rs = scene["particles"][0]["density"]; rl = scene["fluids"][0]["density"]
    t_ref = (h0 / (g * (rs - rl) / rs)) ** 0.5
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        frames = [(msg.log_time * 1e-9, m) for _, _, msg, m in reader.iter_decoded_messages(topics=["/mpm/liquid"])]
    out = []
    for target in (0.5, 1.0, 2.0, 4.0):
        t, cloud = min(frames, key=lambda fr: abs(fr[0] / t_ref - target))
        n = len(cloud.data) // cloud.point_stride
        pts = [struct.unpack_from("<7f", cloud.data, i * cloud.point_stride) for i in range(n)]
        tot = sum(p[6] for p in pts); free = sum(p[6] for p in pts if p[5] > 0.5)
        out_ = [p for p in pts if p[0] > L0]
        to = sum(p[6] for p in out_); fo = sum(p[6] for p in out_ if p[5] > 0.5)
        out.append(f"{target}: {free/tot:.2f} all, {fo/to if to else 0:.2f} beyond gate")
    print(run.split('/')[-1], scene["mpm"]["element_size"], scene["mpm"].get("points_per_element"), " | ".join(out))
