"""Real logs decide (issue 36): the default method's held-out error on every shared real log
(bench_realdata's leave-one-out, both judges, three window lengths) is no worse than the
recorded baseline by more than its noise (``benchmarks/realdata_baseline.json``)."""

from __future__ import annotations

import importlib.util
import json
import logging
import sys
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _bench() -> types.ModuleType:
    spec = importlib.util.spec_from_file_location("bench_realdata",
                                                  ROOT / "benchmarks" / "bench_realdata.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("bench_realdata", module)
    spec.loader.exec_module(module)
    return module


@pytest.mark.realdata
def test_the_held_out_real_sums_are_no_worse_than_the_baseline(shared_data: Path) -> None:
    from odocal.preprocess.convert import convert
    from odocal.settings import Settings

    bench = _bench()
    baseline = json.loads((ROOT / "benchmarks" / "realdata_baseline.json").read_text())
    scenes = {d.name: d for d in convert("nuscenes", [shared_data / "nuscenes-can-bus-mini"])}
    segment = shared_data / "comma2k19-example" / "2018-08-02--08-34-47" / "40"
    comma = convert("comma2k19", [segment],
                    settings=Settings().replace(convert={"reference": "fused"}))[0]
    windows = (650, 400, 200)
    table = {}
    logging.disable(logging.WARNING)
    try:
        for logs in ([scenes[s] for s in bench.SINGAPORE], [scenes[s] for s in bench.BOSTON],
                     bench.blocks(comma, 20.0)):
            table.update(bench.leave_one_out(logs, ["inverse"], windows))
    finally:
        logging.disable(logging.NOTSET)
    tolerance = float(baseline["tolerance"])
    for corrected, key in ((False, "as_logged"), (True, "heading_offset_taken_out")):
        for w in windows:
            total = sum(float(row["inverse"][(w, corrected)] or 0.0) for row in table.values())
            assert total <= baseline[key][str(w)] * (1.0 + tolerance), (key, w, total)
