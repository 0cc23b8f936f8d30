#!/usr/bin/env python3
"""Print the solid front over time and the runout of a recorded run.

pip install mcap mcap-protobuf-support protobuf
usage: python3 read_front.py runs/dry_h060/run.mcap
"""
import json
import sys

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap_protobuf.decoder import DecoderFactory


def main(path):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        try:
            reader.get_summary()
            finished = True
        except Exception:  # no footer: the writer was killed; stream what it wrote
            f.seek(0)
            reader = NonSeekingReader(f, decoder_factories=[DecoderFactory()])
            finished = False
        count = 0
        try:
            for _, _, _, m in reader.iter_decoded_messages(topics=["/dem/metrics"], log_time_order=False):
                print(f"{m.t:.6g} {m.t_norm:.6g} {m.front_x:.6g} {m.front_norm:.6g}")
                count += 1
        except Exception as e:  # a killed writer leaves a truncated last record
            if finished:
                raise
            print(f"{path}: recording ends early: {e!r}", file=sys.stderr)
        if count == 0:
            sys.exit(f"{path}: no /dem/metrics messages")
        if not finished:
            sys.exit(f"{path}: no summary (the run did not finish)")
        summary = None
        for record in reader.iter_metadata():
            if record.name == "summary":
                summary = json.loads(record.metadata["json"])
        if summary is None:
            sys.exit(f"{path}: no summary metadata")
        if summary.get("runout") is None:  # JSON has no NaN: serde_json writes null
            summary["runout"] = float("nan")
        print(f"runout {summary['runout']:.6g}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: read_front.py RUN.mcap")
    try:
        main(sys.argv[1])
    except (OSError, McapError) as e:
        sys.exit(f"{sys.argv[1]}: {e!r}")
