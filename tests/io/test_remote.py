"""Logs, settings and mappings named by URL, read from a real S3 API (moto's server, with IAM
authentication) and a real HTTP server on the loopback address: the same answers as the same
files on disk, one-line errors that name the object, no credential in any output."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import odocal
from odocal.errors import ConfigError, DataError, InputFileError
from odocal.io import remote
from odocal.io.drivefile import load_drive
from tests.conftest import run
from tests.servers import RangeHandler, S3Server, free_port, http_server, s3_server


@pytest.fixture(scope="module")
def s3() -> Iterator[S3Server]:
    with s3_server() as server:
        yield server


@pytest.fixture()
def aws(s3: S3Server, monkeypatch: pytest.MonkeyPatch) -> S3Server:
    """The S3 server's credentials and endpoint in this process's environment."""
    for key, value in s3.env().items():
        monkeypatch.setenv(key, value)
    monkeypatch.delenv("AWS_PROFILE", raising=False)
    return s3


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A two-minute drive as Parquet and CSV, and a settings file."""
    root = tmp_path_factory.mktemp("served")
    drive = odocal.simulate(duration_s=150.0, seed=5).drive
    odocal.save_drive(drive, root / "drive.parquet")
    odocal.save_drive(drive, root / "drive.csv")
    (root / "odocal.toml").write_text("[segments]\nlength = 600\n")
    return root


@pytest.fixture(scope="module")
def web(files: Path) -> Iterator[str]:
    with http_server(files) as base:
        yield base


def _estimate(out: Path) -> list[float]:
    data = json.loads((out / "calibration.json").read_text())
    return [data["theta"][n] for n in ("c_e", "c_d", "t_r", "d")] + [data["std"]["c_e"]]


def test_calibrate_reads_s3_and_https_logs_as_it_reads_the_file(
        aws: S3Server, web: str, files: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    url = aws.upload("logs", "runs/drive.parquet", files / "drive.parquet")
    answers = []
    for i, source in enumerate((str(files / "drive.parquet"), url,
                                f"{web}/drive.parquet?X-Amz-Signature=sig-{aws.secret}")):
        code, out, err = run(capsys, "calibrate", source, "--out", str(tmp_path / f"o{i}"),
                             "--no-report", "-q")
        assert code == 0, err
        answers.append(_estimate(tmp_path / f"o{i}"))
        text = (tmp_path / f"o{i}" / "calibration.json").read_text() + out + err
        assert aws.secret not in text and aws.key not in text and "sig-" not in text
    assert answers[0] == answers[1] == answers[2]          # to the last digit


def test_replay_streams_s3_and_https_logs(aws: S3Server, web: str, files: Path,
                                          tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    url = aws.upload("logs", "runs/drive.csv", files / "drive.csv")
    traces = []
    for i, source in enumerate((str(files / "drive.csv"), url, f"{web}/drive.parquet")):
        code, _, err = run(capsys, "replay", source, "--out", str(tmp_path / f"r{i}"),
                           "--no-batch", "--no-report", "-q")
        assert code == 0, err
        traces.append((tmp_path / f"r{i}" / "trace.csv").read_text())
        saved = json.loads((tmp_path / f"r{i}" / "calibration.json").read_text())
        assert saved["inputs"] == [{"name": remote.redact(source)}]
    assert traces[0] == traces[1] == traces[2] and traces[0].count("\n") > 2


def test_settings_and_logs_by_url_give_one_line_errors(
        aws: S3Server, s3: S3Server, web: str, files: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    config = aws.upload("logs", "cfg/odocal.toml", files / "odocal.toml")
    url = aws.upload("logs", "runs/drive.parquet", files / "drive.parquet")
    aws.upload("logs", "runs/cut.parquet", (files / "drive.parquet").read_bytes()[:5000])
    code, _, err = run(capsys, "calibrate", url, "--config", config, "--out",
                       str(tmp_path / "c"), "--no-report", "-q")
    assert code == 0, err
    assert json.loads((tmp_path / "c" / "calibration.json").read_text()
                      )["settings"]["segments"]["length"] == 600
    dead = f"http://127.0.0.1:{free_port()}/drive.parquet"
    cases = [("s3://logs/runs/missing.parquet", "does not exist"),
             ("s3://logs/runs/cut.parquet", "cannot be read as PARQUET"),
             (dead, "cannot be reached"),
             (f"{web}/nothing.parquet", "does not exist"),
             ("ftp://host/x.parquet", "odocal reads"),
             ("https://me:pw@host/x.parquet", "carries a password")]
    for source, words in cases:
        code, _, err = run(capsys, "calibrate", source, "--out", str(tmp_path / "x"), "-q")
        assert code == 1 and words in err and err.count("\n") == 1, (source, err)
        assert "me:pw" not in err and remote.redact(source) in err
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "not-the-secret")       # wrong credentials
    code, _, err = run(capsys, "calibrate", url, "--out", str(tmp_path / "x"), "-q")
    assert code == 1 and "access denied" in err and err.count("\n") == 1
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", s3.denied_key)              # may list, not read
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", s3.denied_secret)
    code, _, err = run(capsys, "calibrate", url, "--out", str(tmp_path / "x"), "-q")
    assert code == 1 and "access denied" in err
    for secret in (s3.secret, s3.key, s3.denied_secret, s3.denied_key, "not-the-secret"):
        assert secret not in err
    assert not (tmp_path / "x").exists()


def test_a_flaky_server_is_tried_again_a_bounded_number_of_times(
        web: str, files: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    reference = load_drive(files / "drive.parquet")
    monkeypatch.setattr(RangeHandler, "failures", {"/drive.parquet": remote.ATTEMPTS - 1})
    drive = load_drive(f"{web}/drive.parquet")
    assert drive.metadata["sha256"] == reference.metadata["sha256"]
    assert (drive.n_rl == reference.n_rl).all()
    monkeypatch.setattr(RangeHandler, "failures", {"/drive.parquet": remote.ATTEMPTS})
    with pytest.raises(InputFileError, match=r"drive file '.*/drive.parquet' cannot be read"):
        load_drive(f"{web}/drive.parquet")


def test_an_object_that_changed_since_it_was_planned_is_not_read(
        aws: S3Server, files: Path) -> None:
    url = aws.upload("logs", "runs/moving.parquet", files / "drive.parquet")
    info = remote.stat(url)
    aws.upload("logs", "runs/moving.parquet", files / "drive.csv")
    with pytest.raises(InputFileError, match="changed since odocal first looked at it"):
        load_drive(url, pin=info.pin())


def test_an_object_overwritten_in_the_same_second_with_as_many_bytes_is_another_version(
        aws: S3Server) -> None:
    """The fingerprint a fleet's store keys what it has read on: the size and the modification
    time (to the second) cannot tell these two versions apart; the ETag does."""
    for _ in range(5):                          # (again where the two writes straddle a second)
        url = aws.upload("logs", "runs/same.csv", b"t,n_rl\n0,1.0\n")
        before = remote.stat(url)
        aws.upload("logs", "runs/same.csv", b"t,n_rl\n0,2.0\n")
        after = remote.stat(url)
        if before.modified == after.modified:
            break
    assert before.modified == after.modified and before.size == after.size
    assert before.etag != after.etag
    assert before.fingerprint() != after.fingerprint()


def test_an_object_that_changes_under_replay_is_named(aws: S3Server, files: Path) -> None:
    from odocal.online.replay import stream_drive_file

    url = aws.upload("logs", "runs/live.parquet", files / "drive.parquet")
    chunks = stream_drive_file(url, rows=500)
    next(chunks)
    aws.upload("logs", "runs/live.parquet", files / "drive.csv")
    with pytest.raises(InputFileError, match=r"'s3://logs/runs/live.parquet' changed"):
        for _ in chunks:
            pass


def test_a_catalog_entry_resolves_against_the_catalog_url() -> None:
    base = "s3://fleet/2026/catalog.csv?versionId=abc"
    assert remote.join(base, "car1/d.parquet") == "s3://fleet/2026/car1/d.parquet"
    assert remote.join(base, "../old/d.parquet") == "s3://fleet/old/d.parquet"
    assert remote.join(base, "/top/d.parquet") == "s3://fleet/top/d.parquet"
    assert remote.join("https://h:8/a/b/c.csv", "d e.parquet") == "https://h:8/a/b/d%20e.parquet"
    assert remote.join(base, "gs://other/x.parquet") == "gs://other/x.parquet"
    with pytest.raises(DataError, match="climbs above"):
        remote.join(base, "../../../x.parquet")


@pytest.mark.parametrize(("url", "shown"), [
    ("https://user:pw@host:8/a/b.parquet?sig=1#x", "https://host:8/a/b.parquet"),
    ("s3://bucket/k.parquet?versionId=7", "s3://bucket/k.parquet"),
    ("/local/path?.parquet", "/local/path?.parquet")])
def test_urls_are_shown_without_credentials_or_queries(url: str, shown: str) -> None:
    assert remote.redact(url) == shown


def test_credential_values_never_leave_in_a_message(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "s3cr3t-value")
    text = remote.clean("signature for s3cr3t-value at https://u:p@h/x?token=abc failed\nmore")
    assert text == "signature for *** at https://h/x failed more"
    with pytest.raises(ConfigError, match="carries a password"):
        remote.check_url("https://u:p@h/x")


def test_without_the_remote_extra_the_error_says_what_to_install(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import builtins

    real = builtins.__import__

    def no_gcsfs(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "gcsfs":
            raise ImportError("No module named 'gcsfs'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_gcsfs)
    with pytest.raises(odocal.errors.MissingDependencyError, match=r"odocal\[remote\]"):
        remote.filesystem("gs://bucket/x.parquet")


def test_file_urls_are_local_paths(files: Path) -> None:
    drive = load_drive((files / "drive.parquet").as_uri())
    assert drive.metadata["sha256"] == load_drive(files / "drive.parquet").metadata["sha256"]
    assert os.fspath(remote.local_path("file:///a%20b/c.parquet")) == "/a b/c.parquet"


def test_raw_logs_and_their_mapping_by_url(aws: S3Server, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """The ``table`` format from a bucket: the mapping an object too, the files it names
    beside it; the same answer as the same files on disk."""
    from tests.preprocess.test_convert import MAPPING, write_tables

    drive = odocal.simulate(duration_s=150.0, seed=6).drive
    write_tables(drive, tmp_path)
    (tmp_path / "map.toml").write_text(MAPPING)
    for name in ("wheels.csv", "imu.csv", "pose.csv", "map.toml"):
        aws.upload("logs", f"tab/{name}", tmp_path / name)
    answers = []
    for i, (logs, mapping) in enumerate([
            ([str(tmp_path / "wheels.csv")], str(tmp_path / "map.toml")),
            (["s3://logs/tab/wheels.csv"], "s3://logs/tab/map.toml")]):
        code, _, err = run(capsys, "calibrate", "--from", "table", *logs, "--mapping", mapping,
                           "--out", str(tmp_path / f"o{i}"), "--no-report", "-q")
        assert code == 0, err
        answers.append(_estimate(tmp_path / f"o{i}"))
    assert answers[0] == answers[1]


# ---------------------------------------------------------------- issue 40

def test_a_server_without_byte_ranges_serves_replay_and_calibrate(
        files: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A plain HTTP server that ignores Range (the whole file every time): replay copies the
    object here first and gives the trace the file gives (on main: fsspec's "Open with
    block_size=0"); calibrate reads a log longer than one 8 MiB request of it."""
    big = tmp_path / "served"
    big.mkdir()
    odocal.save_drive(odocal.simulate(duration_s=1500.0, seed=6).drive, big / "long.csv")
    assert (big / "long.csv").stat().st_size > remote.CHUNK_BYTES
    (big / "drive.parquet").write_bytes((files / "drive.parquet").read_bytes())
    with http_server(big, ranges=False) as plain:
        code, _, err = run(capsys, "replay", f"{plain}/drive.parquet", "--out",
                           str(tmp_path / "r"), "--no-batch", "--no-report", "-q")
        assert code == 0, err
        code, _, err = run(capsys, "calibrate", f"{plain}/long.csv", "--out",
                           str(tmp_path / "c"), "--no-report", "-q")
        assert code == 0, err
    assert run(capsys, "replay", str(files / "drive.parquet"), "--out", str(tmp_path / "f"),
               "--no-batch", "--no-report", "-q")[0] == 0
    assert (tmp_path / "r" / "trace.csv").read_text() == \
        (tmp_path / "f" / "trace.csv").read_text()
    assert run(capsys, "calibrate", str(big / "long.csv"), "--out", str(tmp_path / "d"),
               "--no-report", "-q")[0] == 0
    assert _estimate(tmp_path / "c") == _estimate(tmp_path / "d")


def test_a_relative_entry_keeps_its_query_and_never_shows_it() -> None:
    """A pre-signed object named relative to a catalog's URL: its query is the URL's query
    (used, never shown), not a part of its path (on main: '%3FX-Amz-Signature=...')."""
    base = "https://h:8/fleet/catalog.csv?X-Amz-Signature=catalogsig"
    entry = "car000/x.parquet?X-Amz-Signature=SIG&X-Amz-Security-Token=TOKEN"
    url = remote.join(base, entry)
    assert url == "https://h:8/fleet/car000/x.parquet?X-Amz-Signature=SIG&" \
                  "X-Amz-Security-Token=TOKEN"
    assert remote.redact(url) == "https://h:8/fleet/car000/x.parquet"
    assert remote.join("s3://b/c.csv", "d e.parquet#frag") == "s3://b/d%20e.parquet"


@pytest.mark.parametrize("text", [
    "drive 'https://h/x.parquet?X-Amz-Signature=SIG&X-Amz-Security-Token=TOKEN' is missing",
    "'https://h/car000/x.parquet%3FX-Amz-Signature%3DSIG%26X-Amz-Security-Token%3DTOKEN'",
    "catalog row 3: '/data/x.parquet?sig=SIG&token=TOKEN' does not exist",
    "https://TOKEN@h/x.parquet and gs://b/k?X-Goog-Signature=SIG",
    "a path x.parquet?se=2026&sp=r&sig=SIG (Azure SAS)",
    "az://c/b?sv=2020&sig=SIG#TOKEN",
])
def test_no_query_userinfo_or_token_survives_a_message(text: str) -> None:
    from odocal.errors import shown

    out = shown(text, 2000)
    assert "SIG" not in out and "TOKEN" not in out
    assert remote.clean(text) == " ".join(out.split())
