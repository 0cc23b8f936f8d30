"""`/dem/state` records of a `coupler run` recording, decoded by the
decoder docs/recording.md carries (its "/dem/state" section, which
`python_state_decoder_in_the_docs_matches_the_layout` checks against
the solver's layout): the grains by id, which `/dem/particles` cannot
give (its points are in the solver's storage order, re-sorted every
`dem.sort_interval` steps).

    from dem_state import states
    for s in states(run_dir):   # s["time"], s["by_id"][id] = (position, velocity, radius)
"""
import pathlib
from mcap.reader import make_reader

_doc = (pathlib.Path(__file__).resolve().parent.parent / "docs" / "recording.md").read_text()
_start = _doc.index("```python\n", _doc.index("A decoder in Python")) + len("```python\n")
exec(_doc[_start:_doc.index("```", _start)])  # defines decode_state


def states(run):
    """Every `/dem/state` of RUN_DIR/run.mcap in time order, each with
    `by_id`: id -> (position, velocity, radius)."""
    out = []
    with open(f"{run}/run.mcap", "rb") as f:
        for _, _, msg in make_reader(f).iter_messages(topics=["/dem/state"]):
            s = decode_state(msg.data)  # noqa: F821 (from the docs' code above)
            s["by_id"] = {i: (p, v, r) for i, p, v, r in zip(s["ids"], s["pos"], s["vel"], s["radius"])}
            out.append(s)
    out.sort(key=lambda s: s["time"])
    return out
