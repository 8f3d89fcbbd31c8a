"""Issue 40's hostile run, round three: odocal attacked as a hostile user would, case by case.

    python benchmarks/hostile_round3.py [--only CLASS,...] [--list] [--case NAME]

Every case runs the ``odocal`` program (as installed, with the odocal that ``PYTHONPATH``
names first: run it with ``PYTHONPATH=src`` for this tree, or another tree's ``src`` to attack
that one) on inputs built here from seeded simulations, and judges what it did against what
the README promises: one line and a non-zero exit for bad input, no traceback, nothing the user
gave overwritten, no secret in any line or file, the same recording never counted twice,
Ctrl-C stopping at once with the earlier results intact and no process left. Classes:
``interrupts``, ``secrets``, ``duplicates``, ``files``, ``fleet``, ``errors`` (errors that
name where), ``general``. Printed: one line per case (ok, or DEFECT with what was wrong), then
the counts by class. Deterministic: seeds fixed, servers on the loopback address.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.interrupting import BIN, interrupt_at, tree_hashes  # noqa: E402

SECRET = "SIGs3cr3tXYZ"
TOKEN = "TOKt0k3nQRS"
PASSWORD = "PWDpa55WRD"
SHARED = Path(os.environ.get("ODOCAL_SHARED_DATA", ROOT.parent / "shared" / "data"))


@dataclass
class Result:
    code: int | None
    out: str
    err: str

    @property
    def said(self) -> list[str]:
        """stderr without the progress lines."""
        return [line for line in self.err.strip().splitlines() if not line.startswith("[")]

    @property
    def text(self) -> str:
        return self.out + self.err


@dataclass
class Ctx:
    tmp: Path
    env: dict[str, str]
    counter: list[int] = field(default_factory=lambda: [0])
    web: str = ""
    plain: str = ""
    served: Path = Path()

    def dir(self, name: str = "") -> Path:
        self.counter[0] += 1
        path = self.tmp / f"c{self.counter[0]:03d}{name}"
        path.mkdir()
        return path

    def cli(self, *argv: str, cwd: Path | None = None, timeout: float = 300.0,
            env: dict[str, str] | None = None) -> Result:
        try:
            proc = subprocess.run([str(BIN / "odocal"), *argv], cwd=cwd or self.tmp,
                                  capture_output=True, text=True, timeout=timeout,
                                  env={**self.env, **(env or {})})
        except subprocess.TimeoutExpired as exc:
            return Result(None, str(exc.stdout or ""), f"TIMEOUT after {timeout} s")
        return Result(proc.returncode, proc.stdout, proc.stderr)


Check = tuple[bool, str]
CASES: list[tuple[str, str, Callable[[Ctx], Check]]] = []


def case(cls: str, name: str) -> Callable[[Callable[[Ctx], Check]], Callable[[Ctx], Check]]:
    def register(fn: Callable[[Ctx], Check]) -> Callable[[Ctx], Check]:
        CASES.append((cls, name, fn))
        return fn
    return register


# ---------------------------------------------------------------- judgements

def one_line_error(r: Result, *words: str, code: int = 1) -> Check:
    """Exit ``code``, one line on stderr (progress aside; for a usage error, exit 2, argparse's
    usage lines before it), no traceback, ``words`` in it."""
    if r.code != code:
        return False, f"exit {r.code}, wanted {code}: {r.err.strip()[-200:]}"
    if code == 2 and r.said and r.said[0].startswith("usage:") and "Traceback" not in r.err:
        last = r.said[-1]
        missing = [w for w in words if w not in last]
        ok = last.startswith("odocal") and ": error: " in last and not missing
        return ok, last[:120] if ok else f"usage error unclear: {last[:200]}"
    if "Traceback" in r.err or len(r.said) != 1:
        return False, f"{len(r.said)} lines / traceback: {r.err.strip()[-200:]}"
    missing = [w for w in words if w not in r.said[0]]
    if missing:
        return False, f"missing {missing!r} in: {r.said[0][:220]}"
    return True, r.said[0][:120]


def succeeded(r: Result, *words: str, code: int = 0) -> Check:
    if r.code != code or "Traceback" in r.err:
        return False, f"exit {r.code}: {r.err.strip()[-200:]}"
    missing = [w for w in words if w not in r.text]
    return (not missing, f"missing {missing!r}" if missing else "as promised")


def no_secret(*texts: str, secrets: Sequence[str] = (SECRET, TOKEN, PASSWORD)) -> Check:
    for s in secrets:
        for text in texts:
            if s in text:
                i = text.index(s)
                return False, f"secret shown: ...{text[max(0, i - 60):i + 20]!r}"
    return True, "no secret anywhere"


def files_text(*folders: Path) -> str:
    out = []
    for folder in folders:
        if folder.is_file():
            out.append(folder.read_bytes().decode("latin-1"))
        elif folder.is_dir():
            out += [p.read_bytes().decode("latin-1") for p in folder.rglob("*") if p.is_file()]
    return "\n".join(out)


def both(*checks: Check) -> Check:
    for ok, why in checks:
        if not ok:
            return False, why
    return True, checks[-1][1]


# ---------------------------------------------------------------- inputs

def _odocal_lib() -> object:
    import odocal

    return odocal


def columns(seconds: float = 600.0, seed: int = 7, noise: str = "realistic"
            ) -> dict[str, np.ndarray]:
    odocal = _odocal_lib()
    d = odocal.simulate(duration_s=seconds, seed=seed, noise=noise).drive  # type: ignore
    return {k: np.asarray(v).copy() for k, v in d.columns().items() if k != "yaw_rate"}


def write(path: Path, cols: dict[str, np.ndarray], types: dict[str, object] | None = None
          ) -> Path:
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    table = pa.table({k: pa.array(np.asarray(v), type=(types or {}).get(k))
                      for k, v in cols.items()})
    if path.suffix == ".csv":
        pacsv.write_csv(table, path)
    else:
        pq.write_table(table, path)
    return path


_CACHE: dict[tuple[object, ...], dict[str, np.ndarray]] = {}


def base(seconds: float = 600.0, seed: int = 7, noise: str = "realistic"
         ) -> dict[str, np.ndarray]:
    key = (seconds, seed, noise)
    if key not in _CACHE:
        _CACHE[key] = columns(seconds, seed, noise)
    return {k: v.copy() for k, v in _CACHE[key].items()}


def drive_file(ctx: Ctx, name: str = "drive.parquet", seconds: float = 600.0, seed: int = 7,
               noise: str = "realistic", folder: Path | None = None) -> Path:
    return write((folder or ctx.dir()) / name, base(seconds, seed, noise))


# ================================================================ secrets

_QUERIES = {
    "aws pre-signed": f"?X-Amz-Signature={SECRET}&X-Amz-Security-Token={TOKEN}",
    "sig and token": f"?sig={SECRET}&token={TOKEN}",
    "percent-encoded": f"%3FX-Amz-Signature%3D{SECRET}%26X-Amz-Security-Token%3D{TOKEN}",
    "azure sas": f"?sv=2020-08-04&se=2026&sp=r&sig={SECRET}",
    "gcs signed": f"?X-Goog-Algorithm=x&X-Goog-Credential={TOKEN}&X-Goog-Signature={SECRET}",
    "api key": f"?api_key={SECRET}&access_token={TOKEN}",
}


def _query_named(ctx: Ctx, query: str, suffix: str = ".parquet") -> Path:
    folder = ctx.dir()
    path = folder / f"drive{suffix}{query}"
    write(folder / f"x{suffix}", base(300.0, 9))
    (folder / f"x{suffix}").rename(path)
    return path


for _label, _query in _QUERIES.items():
    def _calibrate_named(ctx: Ctx, query: str = _query) -> Check:
        path = _query_named(ctx, query)
        out = path.parent / "out"
        r = ctx.cli("calibrate", str(path), "--out", str(out), "--export", "yaml,tum,autoware")
        return both(succeeded(r), no_secret(r.text, files_text(out)))

    case("secrets", f"calibrate a file named with a {_label} query")(_calibrate_named)

for _label in ("aws pre-signed", "percent-encoded"):
    def _replay_named(ctx: Ctx, query: str = _QUERIES[_label]) -> Check:
        path = _query_named(ctx, query)
        out = path.parent / "out"
        r = ctx.cli("replay", str(path), "--out", str(out))
        return both(succeeded(r), no_secret(r.text, files_text(out)))

    case("secrets", f"replay a file named with a {_label} query")(_replay_named)


@case("secrets", "validate and minimum on a file named with a query")
def _validate_named(ctx: Ctx) -> Check:
    path = _query_named(ctx, _QUERIES["sig and token"])
    r1 = ctx.cli("validate", str(path))
    r2 = ctx.cli("minimum", str(path), "--out", str(path.parent / "m.json"), "--seed", "1")
    return both(succeeded(r1), no_secret(r1.text, r2.text, files_text(path.parent / "m.json")))


@case("secrets", "a missing file named with a query")
def _missing_named(ctx: Ctx) -> Check:
    r = ctx.cli("calibrate", str(ctx.dir() / f"gone.parquet{_QUERIES['aws pre-signed']}"),
                "--out", str(ctx.tmp / "never"))
    return both(one_line_error(r, "does not exist"), no_secret(r.text))


@case("secrets", "a URL with a token as its user name (-v)")
def _token_user(ctx: Ctx) -> Check:
    r = ctx.cli("calibrate", f"https://{TOKEN}@127.0.0.1:9/x.parquet?sig={SECRET}#frag",
                "--out", str(ctx.tmp / "never"), "-v")
    return both((r.code == 1, f"exit {r.code}"), no_secret(r.text))


@case("secrets", "a URL with a password is refused without showing it")
def _password(ctx: Ctx) -> Check:
    r = ctx.cli("calibrate", f"https://user:{PASSWORD}@127.0.0.1:9/x.parquet", "--out",
                str(ctx.tmp / "never"))
    return both(one_line_error(r, "carries a password"), no_secret(r.text))


@case("secrets", "an s3 URL with a pre-signed query and no credentials")
def _s3_query(ctx: Ctx) -> Check:
    r = ctx.cli("calibrate", f"s3://bucket/k.parquet{_QUERIES['aws pre-signed']}", "--out",
                str(ctx.tmp / "never"), env={"AWS_ENDPOINT_URL": "http://127.0.0.1:9",
                                             "AWS_ACCESS_KEY_ID": "k", "AWS_SECRET_ACCESS_KEY":
                                             "s", "AWS_DEFAULT_REGION": "us-east-1"},
                timeout=120)
    return both((r.code == 1 and "Traceback" not in r.err, f"exit {r.code}"), no_secret(r.text))


@case("secrets", "a settings URL with a token query (-vv)")
def _config_query(ctx: Ctx) -> Check:
    path = drive_file(ctx, seconds=300.0, seed=9)
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"), "--config",
                f"http://127.0.0.1:9/odocal.toml?token={TOKEN}&sig={SECRET}", "-vv")
    return both((r.code == 1, f"exit {r.code}"), no_secret(r.text))


@case("secrets", "a mapping URL with a query")
def _mapping_query(ctx: Ctx) -> Check:
    r = ctx.cli("convert", str(SHARED / "comma2k19-example"), "--from", "table", "--mapping",
                f"http://127.0.0.1:9/m.toml?X-Amz-Signature={SECRET}", "--out",
                str(ctx.dir() / "x.parquet"))
    return both((r.code == 1, f"exit {r.code}"), no_secret(r.text))


@case("secrets", "replay of an unreachable URL with a token query")
def _replay_url(ctx: Ctx) -> Check:
    r = ctx.cli("replay", f"http://127.0.0.1:9/x.parquet?access_token={TOKEN}", "--out",
                str(ctx.dir() / "o"), "-v")
    return both((r.code == 1, f"exit {r.code}"), no_secret(r.text))


@case("secrets", "a fleet catalog URL with a query that cannot be reached")
def _catalog_url(ctx: Ctx) -> Check:
    r = ctx.cli("fleet", "calibrate", f"http://127.0.0.1:9/c.csv?sig={SECRET}", "--store",
                str(ctx.dir() / "s.db"))
    return both((r.code == 1, f"exit {r.code}"), no_secret(r.text))


@case("secrets", "a served drive read through a pre-signed URL (calibrate and replay)")
def _served_query(ctx: Ctx) -> Check:
    url = f"{ctx.web}/drive.parquet{_QUERIES['aws pre-signed']}"
    folder = ctx.dir()
    r1 = ctx.cli("calibrate", url, "--out", str(folder / "c"), "--export", "yaml,tum")
    r2 = ctx.cli("replay", url, "--out", str(folder / "r"))
    return both(succeeded(r1), succeeded(r2),
                no_secret(r1.text, r2.text, files_text(folder)))


@case("secrets", "a local catalog whose rows carry queries (store and report)")
def _local_catalog_queries(ctx: Ctx) -> Check:
    folder = ctx.dir()
    a = _query_named(ctx, _QUERIES["sig and token"])
    shutil.move(str(a), folder / a.name)
    catalog = folder / "c.csv"
    catalog.write_text(f"vehicle,path,time\ncar,{a.name},2026-01-01\n"
                       f"car,missing.parquet?sig={SECRET},2026-01-02\n")
    r = ctx.cli("fleet", "calibrate", str(catalog), "--store", str(folder / "s.db"), "--out",
                str(folder / "out"), "--workers", "1")
    return both((r.code in (0, 1), f"exit {r.code}"),
                no_secret(r.text, files_text(folder / "out", folder / "s.db")))


@case("secrets", "a served catalog with pre-signed relative rows")
def _served_catalog(ctx: Ctx) -> Check:
    q = _QUERIES["aws pre-signed"]
    (ctx.served / "cat.csv").write_text(f"vehicle,path,time\ncar,drive.parquet{q},2026-01-01\n"
                                        f"car,missing.parquet{q},2026-01-02\n")
    folder = ctx.dir()
    r = ctx.cli("fleet", "calibrate", f"{ctx.web}/cat.csv{q}", "--store", str(folder / "s.db"),
                "--out", str(folder / "out"), "--workers", "1")
    return both((r.code == 1 and "catalog row 2" in r.err, f"exit {r.code}: {r.err[-200:]}"),
                no_secret(r.text, files_text(folder)))


@case("secrets", "a credential variable's value in a path is blanked")
def _env_value(ctx: Ctx) -> Check:
    r = ctx.cli("calibrate", str(ctx.tmp / f"{SECRET}.parquet"), "--out", str(ctx.tmp / "n"),
                env={"AWS_SECRET_ACCESS_KEY": SECRET})
    return both(one_line_error(r, "does not exist"), no_secret(r.text))


@case("secrets", "log lines of a library (-vv) with a URL query")
def _log_lines(ctx: Ctx) -> Check:
    r = ctx.cli("calibrate", f"{ctx.web}/missing.parquet?sig={SECRET}", "--out",
                str(ctx.dir() / "o"), "-vv")
    return both((r.code == 1, f"exit {r.code}"), no_secret(r.text))


# ================================================================ duplicates

def _pair(ctx: Ctx, make: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]],
          name: str = "copy.parquet") -> tuple[Path, Path]:
    folder = ctx.dir()
    a = write(folder / "drive.parquet", base(420.0, 31))
    b = write(folder / name, make(base(420.0, 31)))
    return a, b


def _refused_pair(ctx: Ctx, a: Path, b: Path, *argv: str, words: Sequence[str] = ()) -> Check:
    r = ctx.cli(*(argv or ("calibrate",)), str(a), str(b), "--out", str(a.parent / "o"))
    return both(one_line_error(r, a.name, b.name, *words),
                (not (a.parent / "o").exists(), "results written"))


@case("duplicates", "the same samples as Parquet and CSV")
def _parquet_csv(ctx: Ctx) -> Check:
    a, b = _pair(ctx, lambda c: c, "drive.csv")
    return _refused_pair(ctx, a, b, words=["same drive"])


for _shift in (5000.0, -3000.0, 1.7e9):
    def _shifted(ctx: Ctx, shift: float = _shift) -> Check:
        a, b = _pair(ctx, lambda c: {**c, "t": c["t"] + shift})
        return _refused_pair(ctx, a, b)

    case("duplicates", f"a copy with its clock shifted by {_shift:g} s")(_shifted)


@case("duplicates", "a renamed copy, a symlink and a hard link")
def _links(ctx: Ctx) -> Check:
    a, b = _pair(ctx, lambda c: c)
    link = a.parent / "link.parquet"
    link.symlink_to(a)
    hard = a.parent / "hard.parquet"
    os.link(a, hard)
    rs = [ctx.cli("calibrate", str(a), str(x), "--out", str(a.parent / "o"))
          for x in (b, link, hard)]
    return both(*(one_line_error(r, "same drive") for r in rs))


for _label, _cut in (("first half", (0, 8400)), ("middle third", (5600, 11200)),
                     ("last 200 s", (8800, None))):
    def _cropped(ctx: Ctx, cut: tuple[int, int | None] = _cut) -> Check:
        a, b = _pair(ctx, lambda c: {k: v[cut[0]:cut[1]] for k, v in c.items()})
        return _refused_pair(ctx, a, b, words=["copy"])

    case("duplicates", f"a cropped copy ({_label})")(_cropped)


@case("duplicates", "a copy with a little noise added to the wheels")
def _noisy(ctx: Ctx) -> Check:
    rng = np.random.default_rng(3)

    def noisy(c: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {**c, "n_rl": c["n_rl"] + 0.002 * rng.standard_normal(c["t"].size),
                "n_rr": c["n_rr"] + 0.002 * rng.standard_normal(c["t"].size)}
    a, b = _pair(ctx, noisy)
    return _refused_pair(ctx, a, b, words=["copy"])


@case("duplicates", "a copy starting one sample later, clock shifted")
def _one_later(ctx: Ctx) -> Check:
    a, b = _pair(ctx, lambda c: {k: (v[1:] + 77.7 if k == "t" else v[1:]) for k, v in c.items()})
    return _refused_pair(ctx, a, b)


@case("duplicates", "a CSV copy written with 9 significant digits")
def _rounded(ctx: Ctx) -> Check:
    folder = ctx.dir()
    a = write(folder / "drive.parquet", base(420.0, 31))
    cols = base(420.0, 31)
    lines = [",".join(cols)] + [",".join(f"{cols[k][i]:.9g}" for k in cols)
                                for i in range(cols["t"].size)]
    b = folder / "rounded.csv"
    b.write_text("\n".join(lines) + "\n")
    return _refused_pair(ctx, a, b)


@case("duplicates", "three logs, the third a copy of the first")
def _three(ctx: Ctx) -> Check:
    folder = ctx.dir()
    a = write(folder / "a.parquet", base(420.0, 31))
    b = write(folder / "b.parquet", base(420.0, 32))
    c = write(folder / "c.csv", base(420.0, 31))
    r = ctx.cli("calibrate", str(a), str(b), str(c), "--out", str(folder / "o"))
    return one_line_error(r, "a.parquet", "c.csv")


@case("duplicates", "two different drives are not copies")
def _distinct(ctx: Ctx) -> Check:
    folder = ctx.dir()
    a = write(folder / "a.parquet", base(420.0, 31))
    b = write(folder / "b.parquet", base(420.0, 32))
    return succeeded(ctx.cli("calibrate", str(a), str(b), "--out", str(folder / "o"),
                             "--no-report"), "read 2 drive")


@case("duplicates", "one route driven twice (same motion, other noise) is not a copy")
def _same_route(ctx: Ctx) -> Check:
    folder = ctx.dir()
    a = write(folder / "a.parquet", base(420.0, 33, "realistic"))
    b = write(folder / "b.parquet", base(420.0, 33, "white"))
    return succeeded(ctx.cli("calibrate", str(a), str(b), "--out", str(folder / "o"),
                             "--no-report"), "read 2 drive")


for _cmd in ("validate", "minimum", "calibrate --compare"):
    def _dup_cmd(ctx: Ctx, cmd: str = _cmd) -> Check:
        a, b = _pair(ctx, lambda c: c, "drive.csv")
        argv = cmd.split()
        extra = ["--out", str(a.parent / "o")] if argv[0] != "validate" else []
        r = ctx.cli(*argv, str(a), str(b), *extra)
        return one_line_error(r, "same drive")

    case("duplicates", f"{_cmd} with the same samples twice")(_dup_cmd)


@case("duplicates", "a log holding the same stretch twice as two pieces")
def _twice_in_one(ctx: Ctx) -> Check:
    c = base(420.0, 31)
    n = c["t"].size
    both_ = {k: np.concatenate([v, v + (c["t"][-1] + 100.0 if k == "t" else 0.0)])
             for k, v in c.items()}
    both_["piece"] = np.concatenate([np.zeros(n), np.ones(n)])
    path = write(ctx.dir() / "twice.parquet", both_)
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, "twice.parquet")


@case("duplicates", "a fleet catalog listing Parquet and CSV of one drive")
def _fleet_dup(ctx: Ctx) -> Check:
    a, b = _pair(ctx, lambda c: c, "drive.csv")
    catalog = a.parent / "c.csv"
    catalog.write_text(f"vehicle,path,time\ncar,{a.name},2026-01-01\ncar,{b.name},2026-01-02\n")
    r = ctx.cli("fleet", "calibrate", str(catalog), "--store", str(a.parent / "s.db"),
                "--workers", "1")
    with sqlite3.connect(a.parent / "s.db") as db:
        rows = db.execute("SELECT count(*) FROM drives").fetchone()[0]
    return both((r.code == 1 and "same samples" in r.err, f"exit {r.code}: {r.err[-200:]}"),
                (rows == 1, f"{rows} rows stored"))


# ================================================================ files

def _results(ctx: Ctx, *extra: str) -> tuple[Path, Path]:
    d = drive_file(ctx, seconds=300.0, seed=9)
    out = d.parent / "res"
    r = ctx.cli("calibrate", str(d), "--out", str(out), "--export", "tum", *extra)
    assert r.code == 0, r.err
    return d, out


def _refused_folder(ctx: Ctx, d: Path, out: Path, *words: str) -> Check:
    before = tree_hashes(out)
    r = ctx.cli("calibrate", str(d), "--out", str(out))
    return both(one_line_error(r, *words), (tree_hashes(out) == before, "folder changed"))


for _edit in ("calibration.json", "report.html", "figures/map.png",
              "trajectories/reference.tum"):
    def _edited(ctx: Ctx, rel: str = _edit) -> Check:
        d, out = _results(ctx)
        p = out / rel
        p.write_bytes(p.read_bytes() + b" ")
        return _refused_folder(ctx, d, out, rel, "changed since odocal wrote it")

    case("files", f"an edited {_edit} in a results folder")(_edited)


@case("files", "a file the user added to a results folder")
def _added(ctx: Ctx) -> Check:
    d, out = _results(ctx)
    (out / "figures" / "notes.txt").write_text("mine")
    return _refused_folder(ctx, d, out, "notes.txt", "did not write")


@case("files", "a hidden file the user added")
def _hidden(ctx: Ctx) -> Check:
    d, out = _results(ctx)
    (out / ".mine").write_text("mine")
    return _refused_folder(ctx, d, out, ".mine")


@case("files", "a results file the user deleted (the rest is odocal's)")
def _deleted(ctx: Ctx) -> Check:
    d, out = _results(ctx)
    (out / "report.html").unlink()
    return succeeded(ctx.cli("calibrate", str(d), "--out", str(out), "--no-report"))


@case("files", "a marker whose hash line was edited")
def _marker_edited(ctx: Ctx) -> Check:
    d, out = _results(ctx)
    marker = out / ".odocal-results"
    lines = marker.read_text().splitlines()
    lines[1] = "0" * 64 + lines[1][64:]
    marker.write_text("\n".join(lines) + "\n")
    return _refused_folder(ctx, d, out, "changed since odocal wrote it")


@case("files", "a marker deleted (a folder of odocal's names is still odocal's)")
def _marker_gone(ctx: Ctx) -> Check:
    d, out = _results(ctx, "--no-report")
    (out / ".odocal-results").unlink()
    shutil.rmtree(out / "trajectories")
    return succeeded(ctx.cli("calibrate", str(d), "--out", str(out), "--no-report"))


@case("files", "a marker emptied")
def _marker_empty(ctx: Ctx) -> Check:
    d, out = _results(ctx)
    (out / ".odocal-results").write_text("")
    r = ctx.cli("calibrate", str(d), "--out", str(out), "--no-report")
    return (r.code in (0, 1) and "Traceback" not in r.err, f"exit {r.code}")


@case("files", "calibrate into a folder odocal simulate wrote")
def _into_simulated(ctx: Ctx) -> Check:
    folder = ctx.dir()
    sim = folder / "sim"
    assert ctx.cli("simulate", "--out", f"{sim}/", "--duration", "120", "-q").code == 0
    d = drive_file(ctx, seconds=300.0, seed=9)
    return succeeded(ctx.cli("calibrate", str(d), "--out", str(sim), "--no-report"))


@case("files", "a simulated truth edited by hand")
def _truth_edited(ctx: Ctx) -> Check:
    sim = ctx.dir() / "sim"
    assert ctx.cli("simulate", "--out", f"{sim}/", "--duration", "120", "-q").code == 0
    truth = sim / "drive.truth.json"
    truth.write_text(truth.read_text() + " ")
    d = drive_file(ctx, seconds=300.0, seed=9)
    return _refused_folder(ctx, d, sim, "drive.truth.json", "changed since")


@case("files", "calibrate into a folder odocal convert wrote")
def _into_converted(ctx: Ctx) -> Check:
    conv = ctx.dir() / "conv"
    r = ctx.cli("convert", str(SHARED / "nuscenes-can-bus-mini"), "--from", "nuscenes",
                "--scene", "scene-0061", "--out", f"{conv}/", "-q")
    if r.code != 0:
        return False, f"convert failed: {r.err[-200:]}"
    d = drive_file(ctx, seconds=300.0, seed=9)
    return succeeded(ctx.cli("calibrate", str(d), "--out", str(conv), "--no-report"))


@case("files", "minimum over an edited minimum.json")
def _minimum_edited(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    out = d.parent / "m.json"
    assert ctx.cli("minimum", str(d), "--out", str(out), "-q").code == 0
    out.write_text(out.read_text() + " ")
    before = out.read_bytes()
    r = ctx.cli("minimum", str(d), "--out", str(out))
    return both(one_line_error(r, "changed since odocal wrote it"),
                (out.read_bytes() == before, "replaced"))


@case("files", "simulate over a user's file")
def _simulate_over(ctx: Ctx) -> Check:
    target = ctx.dir() / "mine.parquet"
    target.write_text("precious")
    r = ctx.cli("simulate", "--out", str(target), "--duration", "60")
    return both(one_line_error(r, "odocal did not write it"),
                (target.read_text() == "precious", "replaced"))


@case("files", "--out is a file")
def _out_file(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    target = d.parent / "file"
    target.write_text("mine")
    return one_line_error(ctx.cli("calibrate", str(d), "--out", str(target)), "not a folder")


@case("files", "--out is the input's own folder")
def _out_holds(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    return one_line_error(ctx.cli("calibrate", str(d), "--out", str(d.parent)),
                          "holds the input")


@case("files", "--out is a link to a results folder (the link stays a link)")
def _out_link(ctx: Ctx) -> Check:
    d, out = _results(ctx, "--no-report")
    link = d.parent / "link"
    link.symlink_to(out)
    r = ctx.cli("calibrate", str(d), "--out", str(link), "--no-report")
    return both(succeeded(r), (link.is_symlink(), "the link was replaced"))


@case("files", "a symlink the user put into a results folder")
def _inner_link(ctx: Ctx) -> Check:
    d, out = _results(ctx)
    mine = d.parent / "mine.txt"
    mine.write_text("mine")
    (out / "mine.txt").symlink_to(mine)
    return _refused_folder(ctx, d, out, "mine.txt")


@case("files", "replay into a calibration's results folder")
def _replay_into(ctx: Ctx) -> Check:
    d, out = _results(ctx, "--no-report")
    return succeeded(ctx.cli("replay", str(d), "--out", str(out), "--no-report", "--no-batch"))


@case("files", "calibrate into a fleet report folder")
def _into_fleet(ctx: Ctx) -> Check:
    folder = ctx.dir()
    (folder / "f").mkdir()
    (folder / "f" / ".odocal-fleet").write_text("x")
    (folder / "f" / "index.html").write_text("x")
    d = drive_file(ctx, seconds=300.0, seed=9)
    return one_line_error(ctx.cli("calibrate", str(d), "--out", str(folder / "f")),
                          "did not write")


@case("files", "a relative --out is named where the files end up")
def _relative(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    r = ctx.cli("calibrate", str(d), "--out", "rel", "--export", "yaml", cwd=d.parent)
    wrote = [line[6:] for line in r.out.splitlines() if line.startswith("wrote ")]
    bad = [w for w in wrote if not (d.parent / w).is_file()]
    return both(succeeded(r), (not bad and bool(wrote), f"named but absent: {bad[:2]}"))


# ================================================================ errors that name where

def _broken(ctx: Ctx, change: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]],
            types: dict[str, object] | None = None, name: str = "log.parquet") -> Path:
    return write(ctx.dir() / name, change(base()), types)


def _at(c: dict[str, np.ndarray], key: str, index: int | slice, value: float
        ) -> dict[str, np.ndarray]:
    c[key] = c[key].astype(np.float64)
    c[key][index] = value
    return c


for _key in ("n_rl", "n_rr", "a_y", "x", "y", "psi"):
    def _replay_nan(ctx: Ctx, key: str = _key) -> Check:
        path = _broken(ctx, lambda c: _at(c, key, 5000, np.nan))
        r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
        return one_line_error(r, f"'{path}'", f"column {key}", "row 5001", "t=125")

    case("errors", f"replay: NaN in {_key} at row 5001")(_replay_nan)


@case("errors", "replay: inf in t")
def _replay_inf_t(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: _at(c, "t", 3000, np.inf))
    r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, f"'{path}'", "column t", "row 3001")


@case("errors", "replay: a duplicate stamp")
def _replay_dup(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: _at(c, "t", 6000, float(c["t"][5999])))
    r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, f"'{path}'", "not strictly increasing", "row 6001")


@case("errors", "replay: time running backwards")
def _replay_back(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: _at(c, "t", 8000, float(c["t"][7990])))
    r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, f"'{path}'", "not strictly increasing", "row 8001")


@case("errors", "replay: wheel rates of 500 rev/s in n_rr")
def _replay_fast(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: _at(c, "n_rr", slice(7000, 7100), 500.0))
    r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, f"'{path}'", "column n_rr reaches 500", "row 7001")


@case("errors", "replay: a word in a CSV's number column")
def _replay_word(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: c, name="log.csv")
    lines = path.read_text().splitlines()
    cells = lines[4000].split(",")
    cells[1] = "oops"
    lines[4000] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, f"'{path}'")


@case("errors", "replay: a piece column")
def _replay_piece(ctx: Ctx) -> Check:
    def two(c: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        c["piece"] = (np.arange(c["t"].size) >= 12000).astype(np.float64)
        return c
    path = _broken(ctx, two)
    r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, f"'{path}'", "piece", "row 12001")


def _held(every: int) -> Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]]:
    def held(c: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        idx = (np.arange(c["t"].size) // every) * every
        for k in ("x", "y", "psi"):
            c[k] = c[k][idx]
        return c
    return held


for _every, _hz in ((40, "1 Hz"), (4, "10 Hz"), (8, "5 Hz")):
    def _held_case(ctx: Ctx, every: int = _every, hz: str = _hz) -> Check:
        path = _broken(ctx, _held(every))
        r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
        return one_line_error(r, "held between the updates", hz)

    case("errors", f"a reference held at {_hz}")(_held_case)


def _rates(first_step: float, count: int) -> Callable[[dict[str, np.ndarray]],
                                                       dict[str, np.ndarray]]:
    def change(c: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        slow = np.arange(count) * first_step
        fast = slow[-1] + 0.025 * (1 + np.arange(c["t"].size - 4 * count))
        t = np.concatenate([slow, fast])
        return {k: np.interp(t, c["t"], v) if k != "t" else t for k, v in c.items()}
    return change


@case("errors", "10 Hz, then 40 Hz")
def _rate_10_40(ctx: Ctx) -> Check:
    path = _broken(ctx, _rates(0.1, 400))
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, "changes its rate", "10 Hz", "40 Hz")


@case("errors", "40 Hz, then 20 Hz at the end")
def _rate_40_20(ctx: Ctx) -> Check:
    def change(c: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        t = np.concatenate([c["t"][:20000], c["t"][19999] + 0.05 * (1 + np.arange(1000))])
        return {k: np.interp(t, c["t"], v) if k != "t" else t for k, v in c.items()}
    path = _broken(ctx, change)
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, "changes its rate", "20 Hz")


@case("errors", "epoch seconds as 32-bit floats")
def _epoch32(ctx: Ctx) -> Check:
    import pyarrow as pa

    path = _broken(ctx, lambda c: {**c, "t": (1.7e9 + c["t"]).astype(np.float32)},
                   {"t": pa.float32()})
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, "32-bit precision")


@case("errors", "epoch seconds as 32-bit floats, replayed")
def _epoch32_replay(ctx: Ctx) -> Check:
    import pyarrow as pa

    path = _broken(ctx, lambda c: {**c, "t": (1.7e9 + c["t"]).astype(np.float32)},
                   {"t": pa.float32()})
    r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, "32-bit precision")


@case("errors", "a heading in degrees is called degrees")
def _degrees(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: {**c, "psi": np.degrees(c["psi"])})
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, "degrees")


@case("errors", "a noisy heading in radians is not called degrees")
def _noisy_psi(ctx: Ctx) -> Check:
    rng = np.random.default_rng(0)
    path = _broken(ctx, lambda c: {**c, "psi": c["psi"] + rng.normal(0, 0.2, c["t"].size)})
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
    ok, why = one_line_error(r, "noisy or jumps")
    return (ok and "degrees?" not in r.err, why)


@case("errors", "wheel rates with a flipped sign (no RuntimeWarning)")
def _negated(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: {**c, "n_rl": -c["n_rl"], "n_rr": -c["n_rr"]})
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"), "--no-report")
    return both((r.code == 3 and "sign is flipped" in r.out, f"exit {r.code}"),
                ("RuntimeWarning" not in r.err and "Traceback" not in r.err, r.err[-200:]))


@case("errors", "a 10 s drive (no 'K = 650 steps')")
def _ten_s(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: {k: v[:401] for k, v in c.items()})
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
    ok, why = one_line_error(r, "10.0 s", "too short")
    return (ok and "K = " not in r.err, why)


@case("errors", "a 10 s drive replayed")
def _ten_s_replay(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: {k: v[:401] for k, v in c.items()})
    r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
    return (r.code in (0, 1, 3) and "Traceback" not in r.err and "K = " not in r.text,
            f"exit {r.code}: {r.err[-160:]}")


@case("errors", "an hour parked with 2 cm of pose jitter adds no distance")
def _parked(ctx: Ctx) -> Check:
    c = base()
    park = 144000
    rng = np.random.default_rng(1)
    cols = {"t": np.concatenate([np.arange(park) * 0.025, park * 0.025 + c["t"]])}
    for k in ("n_rl", "n_rr", "a_y", "beta"):
        cols[k] = np.concatenate([np.zeros(park), c[k]])
    for k in ("x", "y"):
        cols[k] = np.concatenate([c[k][0] + 0.02 * rng.standard_normal(park), c[k]])
    cols["psi"] = np.concatenate([np.full(park, c["psi"][0]), c["psi"]])
    path = write(ctx.dir() / "parked.parquet", cols)
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"), "--no-report")
    return succeeded(r, "70.0 min, 5.5")


@case("errors", "a burst of 2621 rev/s in batch")
def _burst(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: _at(c, "n_rl", slice(7000, 7100), 2621.0))
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, "column n_rl reaches 2621", "t=175.000 s")


@case("errors", "a good log beside one with swapped wheels names it")
def _swapped_beside(ctx: Ctx) -> Check:
    folder = ctx.dir()
    good = write(folder / "good.parquet", base(600.0, 41))
    c = base(600.0, 40)
    c["n_rl"], c["n_rr"] = c["n_rr"].copy(), c["n_rl"].copy()
    bad = write(folder / "swapped.parquet", c)
    r = ctx.cli("calibrate", str(good), str(bad), "--out", str(folder / "o"), "--no-report")
    return ((r.code == 3 and f"wheels of '{bad}'" in r.out
             and "no differential information" not in r.out), f"exit {r.code}")


@case("errors", "a 2 s gap is named with its time")
def _gap(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: {**c, "t": np.where(np.arange(c["t"].size) >= 9000,
                                                      c["t"] + 2.0, c["t"])})
    r = ctx.cli("calibrate", str(path), "--out", str(path.parent / "o"))
    return one_line_error(r, "a gap of 2.02", "t=224.975 s")


# ================================================================ fleet

def _served_catalog_with(ctx: Ctx, rows: str) -> tuple[Result, Path]:
    name = f"cat{ctx.counter[0]}.csv"
    (ctx.served / name).write_text("vehicle,path,time\n" + rows)
    folder = ctx.dir()
    r = ctx.cli("fleet", "calibrate", f"{ctx.web}/{name}", "--store", str(folder / "s.db"),
                "--workers", "1", "--no-drive-reports")
    return r, folder


def _stored(folder: Path) -> int:
    if not (folder / "s.db").exists():
        return 0
    with sqlite3.connect(folder / "s.db") as db:
        return int(db.execute("SELECT count(*) FROM drives").fetchone()[0])


@case("fleet", "a remote catalog's file:// row that exists (no drive)")
def _file_row(ctx: Ctx) -> Check:
    junk = ctx.dir() / "notes.txt"
    junk.write_text("not a drive\n")
    r, folder = _served_catalog_with(ctx, f"car,drive.parquet,2026-01-01\n"
                                          f"car,file://{junk},2026-01-02\n")
    return both((r.code == 1 and "catalog row 2" in r.err, f"exit {r.code}: {r.err[-200:]}"),
                (_stored(folder) == 1, f"{_stored(folder)} stored"))


@case("fleet", "a remote catalog's file:// row that is missing")
def _file_row_missing(ctx: Ctx) -> Check:
    r, folder = _served_catalog_with(ctx, "car,drive.parquet,2026-01-01\n"
                                          "car,file:///nonexistent/x.parquet,2026-01-02\n")
    return both((r.code == 1 and "catalog row 2" in r.err, f"exit {r.code}: {r.err[-200:]}"),
                (_stored(folder) == 1, f"{_stored(folder)} stored"))


@case("fleet", "a server without byte ranges: calibrate a long CSV")
def _plain_calibrate(ctx: Ctx) -> Check:
    return succeeded(ctx.cli("calibrate", f"{ctx.plain}/long.csv", "--out",
                             str(ctx.dir() / "o"), "--no-report"))


@case("fleet", "a server without byte ranges: replay")
def _plain_replay(ctx: Ctx) -> Check:
    return succeeded(ctx.cli("replay", f"{ctx.plain}/drive.parquet", "--out",
                             str(ctx.dir() / "o"), "--no-report", "--no-batch"))


@case("fleet", "a server without byte ranges: a fleet")
def _plain_fleet(ctx: Ctx) -> Check:
    name = "plaincat.csv"
    (ctx.served / name).write_text("vehicle,path,time\ncar,drive.parquet,2026-01-01\n")
    folder = ctx.dir()
    r = ctx.cli("fleet", "calibrate", f"{ctx.plain}/{name}", "--store", str(folder / "s.db"),
                "--workers", "1", "--no-drive-reports")
    return both(succeeded(r), (_stored(folder) == 1, "not stored"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@case("fleet", "a closed scheduler port fails at once (--connect-timeout 600)")
def _closed_port(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    catalog = d.parent / "c.csv"
    catalog.write_text(f"vehicle,path,time\ncar,{d.name},2026-01-01\n")
    r = ctx.cli("fleet", "calibrate", str(catalog), "--store", str(d.parent / "s.db"),
                "--scheduler", f"tcp://127.0.0.1:{_free_port()}", "--connect-timeout", "600",
                timeout=60)
    return one_line_error(r, "connection refused")


@case("fleet", "a scheduler on an unknown host")
def _unknown_host(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    catalog = d.parent / "c.csv"
    catalog.write_text(f"vehicle,path,time\ncar,{d.name},2026-01-01\n")
    r = ctx.cli("fleet", "calibrate", str(catalog), "--store", str(d.parent / "s.db"),
                "--scheduler", "tcp://no-such-host.invalid:8786", timeout=60)
    return one_line_error(r, "not known")


@case("fleet", "a scheduler address with a path")
def _address_path(ctx: Ctx) -> Check:
    r = ctx.cli("fleet", "calibrate", "c.csv", "--store", str(ctx.dir() / "s.db"),
                "--scheduler", "tcp://127.0.0.1:8786/x")
    return one_line_error(r, "scheduler")


@case("fleet", "a silent scheduler with --connect-timeout 1")
def _silent(ctx: Ctx) -> Check:
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    try:
        d = drive_file(ctx, seconds=300.0, seed=9)
        catalog = d.parent / "c.csv"
        catalog.write_text(f"vehicle,path,time\ncar,{d.name},2026-01-01\n")
        r = ctx.cli("fleet", "calibrate", str(catalog), "--store", str(d.parent / "s.db"),
                    "--scheduler", f"tcp://127.0.0.1:{server.getsockname()[1]}",
                    "--connect-timeout", "1", timeout=60)
    finally:
        server.close()
    return one_line_error(r, "no answer within 1 s")


@case("fleet", "a local catalog row that is a folder")
def _folder_row(ctx: Ctx) -> Check:
    folder = ctx.dir()
    (folder / "sub").mkdir()
    d = drive_file(ctx, seconds=300.0, seed=9, folder=folder)
    catalog = folder / "c.csv"
    catalog.write_text(f"vehicle,path,time\ncar,{d.name},2026-01-01\ncar,sub,2026-01-02\n")
    r = ctx.cli("fleet", "calibrate", str(catalog), "--store", str(folder / "s.db"),
                "--workers", "1")
    return (r.code == 1 and "catalog row 2" in r.err and "Traceback" not in r.err,
            f"exit {r.code}: {r.err[-200:]}")


@case("fleet", "fleet --out is a file")
def _fleet_out_file(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    catalog = d.parent / "c.csv"
    catalog.write_text(f"vehicle,path,time\ncar,{d.name},2026-01-01\n")
    (d.parent / "out").write_text("mine")
    r = ctx.cli("fleet", "calibrate", str(catalog), "--store", str(d.parent / "s.db"),
                "--out", str(d.parent / "out"))
    return both(one_line_error(r, "not a folder"),
                ((d.parent / "out").read_text() == "mine", "replaced"))


@case("fleet", "the same bytes twice in a catalog")
def _fleet_same_bytes(ctx: Ctx) -> Check:
    folder = ctx.dir()
    d = drive_file(ctx, seconds=300.0, seed=9, folder=folder)
    shutil.copy(d, folder / "copy.parquet")
    catalog = folder / "c.csv"
    catalog.write_text(f"vehicle,path,time\ncar,{d.name},2026-01-01\n"
                       "car,copy.parquet,2026-01-02\n")
    r = ctx.cli("fleet", "calibrate", str(catalog), "--store", str(folder / "s.db"))
    return one_line_error(r, "same drive")


# ================================================================ general

@case("general", "an empty file")
def _empty(ctx: Ctx) -> Check:
    p = ctx.dir() / "e.parquet"
    p.write_bytes(b"")
    return one_line_error(ctx.cli("calibrate", str(p), "--out", str(p.parent / "o")), "empty")


@case("general", "a CSV of a header only")
def _header(ctx: Ctx) -> Check:
    p = ctx.dir() / "h.csv"
    p.write_text("t,n_rl,n_rr,a_y,x,y,psi\n")
    return one_line_error(ctx.cli("calibrate", str(p), "--out", str(p.parent / "o")))


@case("general", "garbage bytes as Parquet")
def _garbage(ctx: Ctx) -> Check:
    p = ctx.dir() / "g.parquet"
    p.write_bytes(np.random.default_rng(0).bytes(5000))
    return one_line_error(ctx.cli("calibrate", str(p), "--out", str(p.parent / "o")))


@case("general", "a name of 300 characters")
def _long_name(ctx: Ctx) -> Check:
    return one_line_error(ctx.cli("calibrate", str(ctx.dir() / ("x" * 300 + ".parquet")),
                                  "--out", str(ctx.tmp / "o")))


@case("general", "control characters in a name")
def _control(ctx: Ctx) -> Check:
    r = ctx.cli("calibrate", str(ctx.dir() / "a\x1b[31mred\r.parquet"), "--out",
                str(ctx.tmp / "o"))
    ok, why = one_line_error(r)
    return (ok and "\x1b" not in r.err and "\r" not in r.err, why)


@case("general", "a unicode name")
def _unicode(ctx: Ctx) -> Check:
    p = drive_file(ctx, name="fahrt-über-brücke-日本.parquet", seconds=300.0, seed=9)
    return succeeded(ctx.cli("calibrate", str(p), "--out", str(p.parent / "o"), "--no-report"))


@case("general", "/dev/null as a log")
def _devnull(ctx: Ctx) -> Check:
    return one_line_error(ctx.cli("calibrate", "/dev/null", "--out", str(ctx.tmp / "o")))


@case("general", "a folder as a log")
def _folder_log(ctx: Ctx) -> Check:
    return one_line_error(ctx.cli("calibrate", str(ctx.dir()), "--out", str(ctx.tmp / "o")),
                          "folder")


for _sheet in ("c_e=abc", "c_e=-1", "c_e=1e300", "x=1", "c_e=", "c_e=nan"):
    def _datasheet(ctx: Ctx, sheet: str = _sheet) -> Check:
        d = drive_file(ctx, seconds=300.0, seed=9)
        r = ctx.cli("calibrate", str(d), "--out", str(d.parent / "o"), "--datasheet", sheet)
        return one_line_error(r, code=r.code if r.code in (1, 2) else 1)

    case("general", f"--datasheet {_sheet}")(_datasheet)


for _argv in (["--export", "foo"], ["--workers", "-1"], ["--seed", "-1"],
              ["--method", "magic"], ["--circumference", "0"]):
    def _bad_arg(ctx: Ctx, argv: list[str] = _argv) -> Check:
        d = drive_file(ctx, seconds=300.0, seed=9)
        r = ctx.cli("calibrate", str(d), "--out", str(d.parent / "o"), *argv)
        return one_line_error(r, code=2) if r.code == 2 else one_line_error(r)

    case("general", f"calibrate {' '.join(_argv)}")(_bad_arg)


for _dur in ("0", "-5", "1e9", "nan"):
    def _duration(ctx: Ctx, dur: str = _dur) -> Check:
        r = ctx.cli("simulate", "--out", str(ctx.dir() / "s.parquet"), "--duration", dur)
        return one_line_error(r, code=2)

    case("general", f"simulate --duration {_dur}")(_duration)


@case("general", "a settings file with an unknown key")
def _unknown_key(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    cfg = d.parent / "c.toml"
    cfg.write_text("[segments]\nlenght = 600\n")
    return one_line_error(ctx.cli("calibrate", str(d), "--out", str(d.parent / "o"), "--config",
                                  str(cfg)), "lenght")


@case("general", "a settings file that is not TOML")
def _not_toml(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    cfg = d.parent / "c.toml"
    cfg.write_text("[[[\n")
    return one_line_error(ctx.cli("calibrate", str(d), "--out", str(d.parent / "o"), "--config",
                                  str(cfg)))


@case("general", "validate --params that is not JSON")
def _params(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    p = d.parent / "p.json"
    p.write_text("{nope")
    return one_line_error(ctx.cli("validate", str(d), "--params", str(p)), "JSON")


@case("general", "replay --from rosbag on a Parquet file")
def _rosbag_parquet(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    r = ctx.cli("replay", str(d), "--from", "rosbag", "--out", str(d.parent / "o"))
    return one_line_error(r)


@case("general", "inspect a Parquet drive as a table without a mapping")
def _inspect(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=300.0, seed=9)
    r = ctx.cli("inspect", str(d), "--from", "table")
    return one_line_error(r)


@case("general", "reproduce --distance-km 0")
def _reproduce_zero(ctx: Ctx) -> Check:
    return one_line_error(ctx.cli("reproduce", "--distance-km", "0"), code=2)


@case("general", "simulate --out x.txt")
def _simulate_txt(ctx: Ctx) -> Check:
    return one_line_error(ctx.cli("simulate", "--out", str(ctx.dir() / "x.txt"), "--duration",
                                  "60"), ".txt")


@case("general", "convert --out over a user's file")
def _convert_over(ctx: Ctx) -> Check:
    target = ctx.dir() / "mine.parquet"
    target.write_text("precious")
    r = ctx.cli("convert", str(SHARED / "nuscenes-can-bus-mini"), "--from", "nuscenes",
                "--scene", "scene-0061", "--out", str(target))
    return both(one_line_error(r, "odocal did not write it"),
                (target.read_text() == "precious", "replaced"))


@case("general", "a drive of one sample")
def _one_sample(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: {k: v[:1] for k, v in c.items()})
    return one_line_error(ctx.cli("calibrate", str(path), "--out", str(path.parent / "o")))


@case("general", "replay of a drive of two samples")
def _two_samples(ctx: Ctx) -> Check:
    path = _broken(ctx, lambda c: {k: v[:2] for k, v in c.items()})
    r = ctx.cli("replay", str(path), "--out", str(path.parent / "o"))
    return (r.code in (0, 1, 3) and "Traceback" not in r.err and len(r.said) <= 1,
            f"exit {r.code}: {r.err[-160:]}")


@case("general", "a drive with a column of text")
def _text_column(ctx: Ctx) -> Check:
    p = ctx.dir() / "t.csv"
    p.write_text("t,n_rl,n_rr,a_y,x,y,psi\n" + "\n".join(
        f"{i * 0.025},a,1,0,0,0,0" for i in range(100)) + "\n")
    return one_line_error(ctx.cli("calibrate", str(p), "--out", str(p.parent / "o")), "n_rl")


@case("general", "a mapping file that does not exist")
def _no_mapping(ctx: Ctx) -> Check:
    r = ctx.cli("convert", str(ctx.dir()), "--from", "table", "--mapping",
                str(ctx.tmp / "nope.toml"), "--out", str(ctx.tmp / "x.parquet"))
    return one_line_error(r, "nope.toml")


# ================================================================ interrupts

def _interrupt(ctx: Ctx, argv: list[str], outputs: list[Path], *, line: str | None = None,
               delay: float = 0.0, cwd: Path | None = None) -> Check:
    o = interrupt_at(argv, outputs=outputs, line=line, delay_s=delay, cwd=cwd or ctx.tmp,
                     env={k: v for k, v in ctx.env.items() if k == "PYTHONPATH"})
    if not o.reached:
        return False, "the moment never came"
    if o.finished:
        return (o.code in (0, 3), f"finished first, exit {o.code}")
    why = (f"exit {o.code}, {o.stop_s:.2f} s, intact {o.intact}, left {len(o.left)}, "
           f"leftovers {len(o.leftovers)}")
    return (o.clean, why if o.clean else why + ": " + o.stderr.strip()[-160:])


def _prev(ctx: Ctx, *argv: str) -> tuple[Path, Path]:
    d = drive_file(ctx, seconds=600.0, seed=7)
    out = d.parent / "prev"
    r = ctx.cli(*argv[:1], str(d), "--out", str(out), "-q", *argv[1:])
    assert r.code in (0, 3), r.err
    return d, out


for _stage in ("read ...", "inverse: fit ...", "validation ...", "report ..."):
    def _int_default(ctx: Ctx, stage: str = _stage) -> Check:
        d, out = _prev(ctx, "calibrate")
        return _interrupt(ctx, ["calibrate", str(d), "--out", str(out)], [out], line=stage)

    case("interrupts", f"calibrate at '{_stage}'")(_int_default)

for _delay in (0.5, 1.5, 3.0):
    def _int_raw(ctx: Ctx, delay: float = _delay) -> Check:
        d, out = _prev(ctx, "calibrate")
        return _interrupt(ctx, ["calibrate", str(d), "--out", str(out), "--method", "raw"],
                          [out], delay=delay)

    case("interrupts", f"calibrate --method raw after {_delay} s")(_int_raw)

for _delay in (0.5, 2.0, 4.0):
    def _int_demo(ctx: Ctx, delay: float = _delay) -> Check:
        out = ctx.dir() / "demo"
        assert ctx.cli("demo", "--duration", "300", "--no-compare", "--out", str(out),
                       "-q").code == 0
        return _interrupt(ctx, ["demo", "--duration", "600", "--out", str(out)], [out],
                          delay=delay)

    case("interrupts", f"demo after {_delay} s")(_int_demo)

for _delay in (1.0, 3.0):
    def _int_reproduce(ctx: Ctx, delay: float = _delay) -> Check:
        out = ctx.dir() / "r.json"
        assert ctx.cli("reproduce", "--distance-km", "0.5", "--no-minimum", "--out", str(out),
                       "-q").code == 0
        return _interrupt(ctx, ["reproduce", "--distance-km", "3", "--out", str(out)], [out],
                          delay=delay)

    case("interrupts", f"reproduce after {_delay} s")(_int_reproduce)


@case("interrupts", "validate of an hour after 1 s")
def _int_validate(ctx: Ctx) -> Check:
    d = drive_file(ctx, seconds=3600.0, seed=7)
    return _interrupt(ctx, ["validate", str(d)], [], delay=1.0)


for _delay in (0.5, 1.5):
    def _int_convert(ctx: Ctx, delay: float = _delay) -> Check:
        out = ctx.dir() / "conv"
        assert ctx.cli("convert", str(SHARED / "nuscenes-can-bus-mini"), "--from", "nuscenes",
                       "--scene", "scene-0061", "--out", f"{out}/", "-q").code == 0
        return _interrupt(ctx, ["convert", str(SHARED / "nuscenes-can-bus-mini"), "--from",
                                "nuscenes", "--out", f"{out}/"], [out], delay=delay)

    case("interrupts", f"convert after {_delay} s")(_int_convert)

for _delay in (0.5, 1.5):
    def _int_simulate(ctx: Ctx, delay: float = _delay) -> Check:
        out = ctx.dir() / "s.parquet"
        assert ctx.cli("simulate", "--out", str(out), "--duration", "60", "-q").code == 0
        return _interrupt(ctx, ["simulate", "--out", str(out), "--duration", "7200"],
                          [out, out.with_name("s.truth.json")], delay=delay)

    case("interrupts", f"simulate after {_delay} s")(_int_simulate)

for _delay in (0.3, 1.0):
    def _int_replay_csv(ctx: Ctx, delay: float = _delay) -> Check:
        folder = ctx.dir()
        d = write(folder / "d.csv", base())
        out = folder / "prev"
        assert ctx.cli("replay", str(d), "--out", str(out), "-q", "--no-batch").code == 0
        return _interrupt(ctx, ["replay", str(d), "--out", str(out)], [out], delay=delay)

    case("interrupts", f"replay of a CSV after {_delay} s")(_int_replay_csv)

for _delay in (1.0, 3.0):
    def _int_minimum(ctx: Ctx, delay: float = _delay) -> Check:
        d = drive_file(ctx, seconds=600.0, seed=7)
        out = d.parent / "m.json"
        assert ctx.cli("minimum", str(d), "--out", str(out), "-q", "--workers", "1").code == 0
        return _interrupt(ctx, ["minimum", str(d), "--out", str(out), "--workers", "1"],
                          [out], delay=delay)

    case("interrupts", f"minimum --workers 1 after {_delay} s")(_int_minimum)


for _stage in ("step 2: compensation ...", "report ..."):
    def _int_comp(ctx: Ctx, stage: str = _stage) -> Check:
        d, out = _prev(ctx, "calibrate")
        return _interrupt(ctx, ["calibrate", str(d), "--out", str(out), "--method",
                                "compensated", "--workers", "2", "--save-inputs"], [out],
                          line=stage, delay=0.3)

    case("interrupts", f"calibrate compensated --save-inputs at '{_stage}' +0.3 s")(_int_comp)


@case("interrupts", "calibrate of a URL while it is copied")
def _int_url(ctx: Ctx) -> Check:
    _, out = _prev(ctx, "calibrate")
    return _interrupt(ctx, ["calibrate", f"{ctx.web}/long.csv", "--out", str(out)], [out],
                      delay=0.8)


for _stage in ("drives ...", "pooled ...", "starting the Dask workers ..."):
    def _int_fleet(ctx: Ctx, stage: str = _stage) -> Check:
        folder = ctx.dir()
        r = ctx.cli("simulate-fleet", "--out", str(folder / "f"), "--vehicles", "2", "--drives",
                    "3", "--duration", "300", "-q")
        assert r.code == 0, r.err
        return _interrupt(ctx, ["fleet", "calibrate", str(folder / "f" / "catalog.csv"),
                                "--store", str(folder / "s.db"), "--out",
                                str(folder / "out"), "--workers", "2"], [], line=stage,
                          delay=0.2)

    case("interrupts", f"fleet at '{_stage}' +0.2 s")(_int_fleet)


@case("interrupts", "simulate-fleet after 1 s")
def _int_simfleet(ctx: Ctx) -> Check:
    folder = ctx.dir()
    return _interrupt(ctx, ["simulate-fleet", "--out", str(folder / "f"), "--vehicles", "4",
                            "--drives", "6", "--duration", "600"], [folder / "f"], delay=1.0)


@case("interrupts", "Ctrl-C twice during calibrate --compare")
def _int_twice(ctx: Ctx) -> Check:
    import signal

    d, out = _prev(ctx, "calibrate")
    before = tree_hashes(out)
    env = {**ctx.env, "ODOCAL_PROGRESS": "lines"}
    proc = subprocess.Popen([str(BIN / "odocal"), "calibrate", str(d), "--out", str(out),
                             "--compare"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, env=env)
    time.sleep(3.0)
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(0.05)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        return False, "did not stop"
    return (proc.returncode == 130 and "Traceback" not in err and tree_hashes(out) == before,
            f"exit {proc.returncode}: {err.strip()[-160:]}")


# ================================================================ running

@contextlib.contextmanager
def servers(root: Path) -> Iterator[tuple[str, str]]:
    import functools
    import http.server
    import threading

    from tests.servers import PlainHandler, RangeHandler

    started = []
    urls = []
    for handler in (RangeHandler, PlainHandler):
        server = http.server.ThreadingHTTPServer(
            ("127.0.0.1", 0), functools.partial(handler, directory=str(root)))
        threading.Thread(target=server.serve_forever, daemon=True).start()
        started.append(server)
        urls.append(f"http://127.0.0.1:{server.server_address[1]}")
    try:
        yield urls[0], urls[1]
    finally:
        for server in started:
            server.shutdown()
            server.server_close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default="")
    parser.add_argument("--case", default="")
    parser.add_argument("--list", action="store_true")
    args = parser.parse_args()
    chosen = [c for c in CASES if (not args.only or c[0] in args.only.split(","))
              and (not args.case or args.case in c[1])]
    if args.list:
        for cls, name, _ in chosen:
            print(f"{cls:<11} {name}")
        print(f"{len(chosen)} cases")
        return
    import odocal

    print(f"odocal under attack: {Path(odocal.__file__).parent}")
    tmp = Path(tempfile.mkdtemp(prefix="hostile3-"))
    env = {**os.environ, "ODOCAL_PROGRESS": "off", "OPENBLAS_NUM_THREADS": "1",
           "OMP_NUM_THREADS": "1"}
    counts: dict[str, list[int]] = {}
    failed: list[str] = []
    started = time.perf_counter()
    try:
        served = tmp / "served"
        served.mkdir()
        write(served / "drive.parquet", base(300.0, 9))
        write(served / "long.csv", base(1500.0, 6))
        with servers(served) as (web, plain):
            ctx = Ctx(tmp=tmp, env=env, web=web, plain=plain, served=served)
            for cls, name, fn in chosen:
                try:
                    ok, why = fn(ctx)
                except Exception as exc:            # the harness's own failure: a defect too
                    ok, why = False, f"harness: {type(exc).__name__}: {exc}"
                counts.setdefault(cls, [0, 0])[0 if ok else 1] += 1
                print(f"{'ok    ' if ok else 'DEFECT'} {cls:<11} {name[:62]:<62} {why[:150]}",
                      flush=True)
                if not ok:
                    failed.append(f"{cls}: {name}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print()
    print(f"{'class':<11} {'cases':>5} {'passed':>6} {'defects':>7}")
    for cls, (good, bad) in counts.items():
        print(f"{cls:<11} {good + bad:>5} {good:>6} {bad:>7}")
    total_good = sum(g for g, _ in counts.values())
    total_bad = sum(b for _, b in counts.values())
    print(f"{'all':<11} {total_good + total_bad:>5} {total_good:>6} {total_bad:>7}   "
          f"({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
