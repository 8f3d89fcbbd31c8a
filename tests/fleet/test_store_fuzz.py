"""Property-based: any sequence of writes and reads of drive results and alarms, under any
vehicle names (any script, slashes, control characters, NUL), on a real SQLite file. Reads
return what was written (the last write of a key wins; NaN reads as None), read-only opens see
the same and change nothing, and nothing raises but a named odocal error."""

from __future__ import annotations

import hashlib
import math
import tempfile
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from odocal.errors import OdocalError
from odocal.fleet.store import open_store
from odocal.io.atomic import file_name
from odocal.model.parameters import PARAMETER_NAMES

names = st.one_of(
    st.text(min_size=1, max_size=30),
    st.sampled_from(["car/1", "car_1", "car 1", "../x", ".", "", "\x00", "\x1b[31m", "ü/ß",
                     "車両", "a" * 300, "car\n1"]))
values = st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=False, width=64))

drive = st.fixed_dictionaries({
    "task_key": st.sampled_from([f"k{i}" for i in range(6)]),
    "vehicle": names,
    "time": st.sampled_from(["2026-01-01T00:00:00+00:00", "2026-02-03T04:05:06+00:00"]),
    "source": st.text(max_size=20),
    "status": st.sampled_from(["converged", "rejected", "error"]),
    "success": st.booleans(),
    "message": st.one_of(st.none(), st.text(max_size=40)),
    **{n: values for n in PARAMETER_NAMES},
    "findings": st.lists(st.text(max_size=10), max_size=3),
})
alarm = st.fixed_dictionaries({
    "vehicle": names, "parameter": st.sampled_from(PARAMETER_NAMES),
    "kind": st.sampled_from(["step", "trend"]),
    "time": st.sampled_from(["2026-01-01", "2026-01-02"]), "detected_time": st.just("2026-01-03"),
    "change": values, "relative_change": values, "confidence": values,
    "drives_to_detect": st.integers(0, 10**6), "km_to_detect": values,
    "message": st.text(max_size=40)})
operation = st.one_of(
    st.tuples(st.just("drive"), drive),
    st.tuples(st.just("alarms"), st.lists(alarm, max_size=4,
                                          unique_by=lambda a: (a["vehicle"], a["parameter"],
                                                               a["kind"], a["time"]))),
    st.tuples(st.just("read"), names),
    st.tuples(st.just("reopen"), st.booleans()))


def _same(stored: Any, written: Any) -> bool:
    if isinstance(written, float) and math.isnan(written):
        return stored is None
    if isinstance(written, bool):
        return stored == int(written)
    if isinstance(written, list):
        import json

        return json.loads(stored) == written
    return bool(stored == written)


def _check(store: Any, drives: dict[tuple[str, str], dict[str, Any]],
           alarms: list[dict[str, Any]]) -> None:
    got = {(r["vehicle"], r["task_key"]): r for r in store.drives()}
    assert got.keys() == drives.keys()
    for key, row in drives.items():
        assert all(_same(got[key][c], v) for c, v in row.items()), (key, got[key], row)
    assert sorted(store.vehicles()) == sorted({r["vehicle"] for r in drives.values()})
    for vehicle in {r["vehicle"] for r in drives.values()} - {""}:
        assert {r["task_key"] for r in store.drives(vehicle)} == \
            {k for (v, k) in drives if v == vehicle}
    stored_alarms = store.alarms()
    assert len(stored_alarms) == len(alarms)
    key = ("vehicle", "parameter", "kind", "time")
    by_key = {tuple(a[k] for k in key): a for a in stored_alarms}
    for a in alarms:
        got_alarm = by_key[tuple(a[k] for k in key)]
        assert all(_same(got_alarm[c], v) for c, v in a.items())


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(operation, min_size=1, max_size=25))
def test_any_writes_and_reads_of_the_store_keep_what_was_written(ops: list[Any]) -> None:
    with tempfile.TemporaryDirectory(prefix="odocal-store-fuzz-") as tmp:
        path = Path(tmp) / "fleet.db"
        # one row per drive (vehicle and content; here the key stands for the content), and a
        # new content at the same source of the same vehicle replaces the old one's row
        drives: dict[tuple[str, str], dict[str, Any]] = {}
        alarms: list[dict[str, Any]] = []
        store = open_store(path)
        try:
            for op, arg in ops:
                if op == "drive":
                    store.add_drive(arg)
                    key = (arg["vehicle"], arg["task_key"])
                    drives = {k: r for k, r in drives.items()
                              if k == key or (r["vehicle"], r["source"]) != (arg["vehicle"],
                                                                             arg["source"])}
                    drives[key] = arg
                elif op == "alarms":
                    store.replace_analysis([], arg)
                    alarms = arg
                elif op == "read":
                    rows = store.drives(arg) if arg else store.drives()
                    assert all(r["vehicle"] == arg for r in rows) if arg else True
                    store.alarms(arg or None)
                    file_name(arg)                      # any name has a file name
                else:
                    store.close()
                    if arg:                             # read-only: sees the same, changes none
                        before = hashlib.sha256(path.read_bytes()).hexdigest()
                        with open_store(path, create=False, read_only=True) as ro:
                            _check(ro, drives, alarms)
                        assert hashlib.sha256(path.read_bytes()).hexdigest() == before
                    store = open_store(path)
            _check(store, drives, alarms)
        except OdocalError:
            pass                                        # refused by name: allowed
        finally:
            store.close()


@settings(max_examples=200, deadline=None)
@given(st.lists(names, min_size=2, max_size=8, unique=True))
def test_distinct_vehicle_names_get_distinct_file_names(vehicles: list[str]) -> None:
    cleaned = [file_name(v) for v in vehicles]
    assert len(set(cleaned)) == len(vehicles)
    for c in cleaned:
        assert c and "/" not in c and "\x00" not in c and not c.startswith(".")
        assert len(c.encode()) <= 120 and all(ch.isprintable() for ch in c)


@settings(max_examples=80, deadline=None)
@given(st.binary(max_size=600))
def test_any_bytes_as_a_store_are_refused_by_name_or_read(data: bytes) -> None:
    """A read-only command on any file: an odocal error or an (empty) answer; the file is
    never changed."""
    with tempfile.TemporaryDirectory(prefix="odocal-store-fuzz-") as tmp:
        path = Path(tmp) / "x.db"
        path.write_bytes(data)
        try:
            with open_store(path, create=False, read_only=True) as ro:
                ro.alarms()
                ro.drives()
        except OdocalError as exc:
            assert "\n" not in str(exc)
        assert path.read_bytes() == data
        assert sorted(p.name for p in Path(tmp).iterdir()) == ["x.db"]
