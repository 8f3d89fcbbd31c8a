"""Real logs decide (issue 36): every subset of the shared Singapore scenes, and of the comma2k19
segment's 20 s blocks, calibrated by the default method as a user would.

The rules: no fit stops at the iteration limit; t_r is identified wherever two of the scenes
that turn (0061, 0916, 1077) are in; and a log added to the others never takes away a
parameter they identify (a scene that stands still or drives straight adds nothing, it does not
subtract).
"""

from __future__ import annotations

import itertools
import logging
from pathlib import Path

import pytest

import odocal
from odocal.estimators.estimate import Status
from odocal.preprocess.convert import convert
from odocal.settings import Settings

SINGAPORE = ("scene-0061", "scene-0796", "scene-0916", "scene-1077", "scene-1100")
TURNING = {"scene-0061", "scene-0916", "scene-1077"}

Results = dict[frozenset[str], odocal.CalibrationResult]


def _every_subset(logs: dict[str, odocal.Drive]) -> Results:
    logging.disable(logging.WARNING)
    try:
        return {frozenset(names): odocal.calibrate([logs[n] for n in names])
                for k in range(1, len(logs) + 1)
                for names in itertools.combinations(sorted(logs), k)}
    finally:
        logging.disable(logging.NOTSET)


@pytest.fixture(scope="module")
def singapore(shared_data: Path) -> Results:
    scenes = {d.name: d for d in convert("nuscenes", [shared_data / "nuscenes-can-bus-mini"])}
    return _every_subset({name: scenes[name] for name in SINGAPORE})


@pytest.fixture(scope="module")
def comma(shared_data: Path) -> Results:
    segment = shared_data / "comma2k19-example" / "2018-08-02--08-34-47" / "40"
    drive = convert("comma2k19", [segment],
                    settings=Settings().replace(convert={"reference": "fused"}))[0]
    cols = drive.columns()
    blocks = {}
    for k, lo in enumerate((drive.t[0], drive.t[0] + 20.0, drive.t[0] + 40.0)):
        keep = (drive.t >= lo) & (drive.t < lo + 20.0)
        blocks[f"block {k + 1}"] = odocal.Drive.from_columns(
            {n: v[keep] for n, v in cols.items()}, name=f"comma block {k + 1}")
    return _every_subset(blocks)


def _identified(result: odocal.CalibrationResult) -> set[str]:
    est = result.estimate
    return {n for n, ok in zip(est.theta.as_dict(), est.identified, strict=True) if ok}


def _lost(results: Results) -> list[str]:
    """Every (subset, added log, parameter) where adding the log lost the parameter."""
    out = []
    for subset, result in results.items():
        for name in set().union(*results) - subset:
            bigger = results[subset | {name}]
            for parameter in sorted(_identified(result) - _identified(bigger)):
                out.append(f"{sorted(subset)} + {name}: {parameter} lost")
    return out


@pytest.mark.realdata
@pytest.mark.parametrize("which", ["singapore", "comma"])
def test_no_real_fit_stops_at_the_iteration_limit(which: str,
                                                 request: pytest.FixtureRequest) -> None:
    results: Results = request.getfixturevalue(which)
    stopped = [sorted(s) for s, r in results.items()
               if r.estimate.status is Status.ITERATION_LIMIT]
    assert not stopped


@pytest.mark.realdata
def test_t_r_is_identified_wherever_two_turning_scenes_are(singapore: Results) -> None:
    wanted = [s for s in singapore if len(s & TURNING) >= 2]
    assert len(wanted) == 16
    missing = [sorted(s) for s in wanted if "t_r" not in _identified(singapore[s])]
    assert not missing
    # and the tracks agree: every estimate within three of its std of the five scenes' one
    everything = singapore[frozenset(SINGAPORE)].estimate
    t_r, std = everything.theta.t_r, everything.std[2]
    for s in wanted:
        est = singapore[s].estimate
        assert abs(est.theta.t_r - t_r) <= 3.0 * max(est.std[2], std), sorted(s)


@pytest.mark.realdata
@pytest.mark.parametrize("which", ["singapore", "comma"])
def test_a_log_added_never_takes_a_parameter_away(which: str,
                                                  request: pytest.FixtureRequest) -> None:
    results: Results = request.getfixturevalue(which)
    assert not _lost(results)


@pytest.mark.realdata
def test_no_real_subset_is_refused(singapore: Results, comma: Results) -> None:
    """A rear axle is never refused as front wheels, nor anything else, on the shared logs
    (the scene that stands still alone says it stands still)."""
    refused = [sorted(s) for results in (singapore, comma) for s, r in results.items()
               if r.estimate.status is Status.REJECTED]
    assert not refused
