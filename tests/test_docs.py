"""The documentation (README.md and docs/): it builds strictly, its API reference covers the
public API, and every command and Python snippet it shows runs (issue 39).

Every ``sh`` block of every page is read command by command, and every command must be run by
this test (``odocal ...``, ``evo_rpe ...``, a variable set), be one of the README's two install
commands (the test command is .ci/run's, run by CI; the demo's ``odocal demo`` is run here), be
a ``pip install`` of extras pyproject.toml defines, or be named in :data:`ELSEWHERE` with the
test that runs it. Every ``python`` block runs too (here, or in the test that
:data:`SNIPPETS_ELSEWHERE` names). A command the docs show that nothing runs fails the test by
name.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

import odocal
from odocal.cli.main import main
from tests.conftest import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
_EXPORTS = ("tests/output/test_export.py::"
            "test_every_export_loads_in_ros2_as_the_upstream_nodes_declare_it")

#: Commands the docs show that need what a test machine does not run here (a ROS 2 graph and
#: its stacks, an object store, a Dask cluster), each with the test that runs that command
#: (with that test's own paths, buckets and node names) and words its source must hold.
ELSEWHERE: dict[str, tuple[str, tuple[str, ...]]] = {
    # the node as a process, with the test's own node name and export folder (its topics are
    # the defaults the page names)
    "odocal ros2 --datasheet c_e=1.95,t_r=1.51 --ros-args -p wheel_topic:=/joint_states "
    "-p imu_topic:=/imu/data -p pose_topic:=/odometry/filtered -p export_dir:=$HOME/odocal": (
        "tests/ros2/test_node.py::test_odocal_ros2_starts_the_node_and_stops_on_ctrl_c",
        ('"ros2", "--datasheet", "c_e=1.95,t_r=1.51"', '"--ros-args"', "export_dir:=")),
    # the four-wheel car's node: its settings file (the test's config fixture writes it) and
    # its parameters, the steering joint and the reference's sideslip (car_rig), the export
    "printf '[vehicle]\\nmodel = \"four_wheel\"\\n' > car.toml": (
        "tests/ros2/test_car.py::"
        "test_the_car_on_ros2_is_replays_car_and_publishes_its_ten_parameters",
        ("config: Path", "car_rig(rig, config")),
    "odocal ros2 --config car.toml --ros-args -p steering_joint:=steering_wheel "
    "-p sideslip_from_reference:=true -p export_dir:=$HOME/odocal": (
        "tests/ros2/test_car.py::"
        "test_the_car_on_ros2_is_replays_car_and_publishes_its_ten_parameters",
        ('car_rig(rig, config, steering_joint="steering_wheel")', 'r.folder / "ackermann"')),
    # the example parameter file, given to a node of the default name as rcl's --params-file
    "odocal ros2 --ros-args --params-file odocal_ros2.params.yaml": (
        "tests/ros2/test_features.py::"
        "test_the_example_parameter_file_is_every_parameter_the_node_takes",
        ('"--ros-args", "--params-file", str(PARAMS_FILE)',)),
    # robot_localization on the node's own odometry: the node's export loaded as ekf_node does
    "ros2 run robot_localization ekf_node --ros-args --params-file "
    "$HOME/odocal/robot_localization/ekf_odometry.yaml": (
        "tests/ros2/test_features.py::test_the_estimate_is_latched_data_with_its_labels",
        ('"ekf_odometry.yaml"', "load_declared(", '"odom0"')),
    # the stacks' nodes load the exports with rcl's --params-file parser: the test loads every
    # file with it into nodes that declare each parameter as the upstream node does
    "ros2 run controller_manager spawner diff_drive_controller --param-file "
    "results/ros2_control/diff_drive_controller.yaml": (
        _EXPORTS, ("_write_all(", "_load(")),
    "ros2 launch autoware_vehicle_velocity_converter vehicle_velocity_converter.launch.xml "
    "config_file:=$PWD/results/autoware/vehicle_velocity_converter.param.yaml": (
        _EXPORTS, ("_write_all(", "vehicle_velocity_converter.param.yaml")),
    "ros2 run robot_localization ekf_node --ros-args --params-file "
    "results/robot_localization/ekf_odometry.yaml": (
        _EXPORTS, ("_write_all(", "_load(")),
    # an object store: moto's S3 server and an HTTP server on loopback, with their URLs
    "odocal calibrate https://logs.example.com/car001/2026-03-02.parquet --out results/": (
        "tests/io/test_remote.py::test_calibrate_reads_s3_and_https_logs_as_it_reads_the_file",
        ('"calibrate", source, "--out"', "{web}/drive.parquet")),
    "odocal replay s3://fleet-logs/car001/2026-03-02.parquet --out replay/": (
        "tests/io/test_remote.py::test_replay_streams_s3_and_https_logs",
        ('"replay", source, "--out"', "aws.upload(")),
    "odocal calibrate --from table s3://fleet-logs/robot7/wheels.csv --mapping "
    "s3://fleet-logs/robot7/robot.toml --out r/": (
        "tests/io/test_remote.py::test_raw_logs_and_their_mapping_by_url",
        ('"calibrate", "--from", "table"', '"--mapping"', "s3://logs/tab/map.toml")),
    # the command's library call (odocal fleet calibrate is a shell around it) on a bucket
    "odocal fleet calibrate s3://fleet-logs/2026/catalog.csv --store fleet.db --out "
    "fleet-report/": (
        "tests/fleet/test_remote_fleet.py::"
        "test_a_fleet_in_a_bucket_gives_the_estimates_of_the_same_drives_on_disk",
        ('calibrate_fleet("s3://fleet/v1/catalog.csv"',)),
    # docs/fleet.md, run below as the page shows it (the fleet extra's Dask cluster)
    **{c: ("tests/test_docs.py::test_the_fleet_pages_commands_run", ("_fleet_commands()",))
       for c in ("odocal fleet demo --out fleet-demo/ --drives 3",
                 "odocal fleet alarms --store fleet-demo/fleet.db --json",
                 "odocal fleet history --store fleet-demo/fleet.db --vehicle car001",
                 "sqlite3 fleet-demo/fleet.db \"SELECT vehicle, time, c_e, c_e_std FROM drives "
                 "ORDER BY vehicle, time\"",
                 "odocal simulate-fleet --out fleet/ --vehicles 2 --drives 2 --duration 300",
                 "odocal fleet calibrate fleet/catalog.csv --store fleet.db --out "
                 "fleet-report/")},
}


#: Pages whose Python blocks need what a test machine does not run here (a ROS 2 node to
#: talk to), each with the test that runs them as the page shows them and words it must hold.
SNIPPETS_ELSEWHERE: dict[str, tuple[str, tuple[str, ...]]] = {
    "docs/ros2.md": (
        "tests/ros2/test_features.py::"
        "test_the_docs_reset_snippet_resets_a_node_of_the_default_name",
        ('"docs" / "ros2.md"', '"```python', "CalibrationNode(")),
}


def blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


def commands(block: str) -> list[str]:
    """The block's commands: continued lines joined, comments after two spaces dropped."""
    out: list[str] = []
    for line in block.replace("\\\n", " ").splitlines():
        line = re.sub(r"\s{2,}#.*$", "", line).strip()
        if line and not line.startswith("#"):
            out.append(re.sub(r"\s+", " ", line))
    return out


def shown() -> list[tuple[Path, str]]:
    return [(page, c) for page in PAGES for b in blocks(page.read_text(), "sh")
            for c in commands(b)]


def readme_commands() -> tuple[str, str]:
    cmds = commands("\n".join(blocks((ROOT / "README.md").read_text(), "sh")[:2]))
    return cmds[0], cmds[1]


def _extras() -> set[str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    return set(project["optional-dependencies"])


def _pip_extras(command: str) -> set[str] | None:
    """The extras a ``pip install`` line names (None: not a pip line)."""
    match = re.search(r"pip install (?:-q )?(?:-e )?'?(?:odocal|\.)(?:\[([\w,]+)\])?'?", command)
    if match is None:
        return None
    return set((match.group(1) or "").split(",")) - {""}


def kind(command: str) -> str:
    first = command.split()[0]
    if command in readme_commands():
        return "readme"
    if command in ELSEWHERE:
        return "elsewhere"
    parts = [part.strip() for part in command.split("&&")]
    if "pip install" in command and all(
            part.startswith(("python3 -m venv ", "pip install ", ".venv/bin/pip install "))
            for part in parts):
        return "pip"
    if re.fullmatch(r"[A-Z_]+=\S+", command):
        return "variable"
    if first in ("odocal", ".venv/bin/odocal", "evo_rpe"):
        return "run"
    return "unknown"


def test_every_command_the_docs_show_is_run_somewhere() -> None:
    unknown = [f"{page.relative_to(ROOT)}: {c}" for page, c in shown() if kind(c) == "unknown"]
    assert unknown == []
    for command, (node, words) in ELSEWHERE.items():
        assert any(c == command for _, c in shown()), f"no page shows {command!r} any more"
        path, name = node.split("::")
        source = (ROOT / path).read_text()
        start = source.index(f"def {name}(")
        end = source.find("\ndef ", start + 1)
        body = source[start:end if end > 0 else len(source)]
        for word in words:
            assert word in body, f"{node} does not hold {word!r}"
    for page, (node, words) in SNIPPETS_ELSEWHERE.items():
        assert blocks((ROOT / page).read_text(), "python"), f"{page} shows no Python any more"
        path, name = node.split("::")
        source = (ROOT / path).read_text()
        start = source.index(f"def {name}(")
        end = source.find("\ndef ", start + 1)
        body = source[start:end if end > 0 else len(source)]
        for word in words:
            assert word in body, f"{node} does not hold {word!r}"


def test_the_readme_commands_come_first_and_ci_runs_the_test_command() -> None:
    text = (ROOT / "README.md").read_text()
    demo, tests = readme_commands()
    assert demo == "python3 -m venv .venv && .venv/bin/pip install . && .venv/bin/odocal demo"
    assert tests.startswith("python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]'")
    assert ".venv/bin/mkdocs build --strict" in tests and tests.endswith(".venv/bin/pytest")
    # the first two blocks of the page, before any heading but the title
    assert text.index(demo) < text.index(tests) < text.index("\n## ")
    assert tests in (ROOT / ".ci" / "run").read_text().splitlines()
    # five minutes of reading: a front door, not a manual
    assert len(text.split()) < 1200


def test_every_pip_line_names_extras_that_exist() -> None:
    extras = _extras()
    lines = [c for _, c in shown() if kind(c) == "pip"]
    assert lines
    for line in lines:
        named = _pip_extras(line)
        assert named is not None and named <= extras, line
    test = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]["test"]
    included = set(re.search(r"odocal\[([\w,]+)\]", " ".join(test)).group(1).split(","))  # type: ignore[union-attr]
    assert included == extras - {"test"}                # the test extra installs every extra


@contextlib.contextmanager
def _in(folder: Path) -> Iterator[None]:
    before = Path.cwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(before)


def _run(command: str, env: dict[str, str], capsys: pytest.CaptureFixture[str]) -> str:
    words = [os.path.expandvars(w) if "$" in w else w for w in shlex.split(command)]
    words = [w.replace("$HOME", env["HOME"]).replace("$PWD", os.getcwd()) for w in words]
    if words[0] == "evo_rpe":
        evo = Path(sys.executable).with_name("evo_rpe")
        if not evo.exists():
            pytest.skip("evo is not installed")
        done = subprocess.run([str(evo), *words[1:]], capture_output=True, text=True,
                              env={**os.environ, "MPLBACKEND": "Agg"})
        assert done.returncode == 0, done.stdout + done.stderr
        return done.stdout
    try:
        code = main(words[1:])
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    assert code == 0, f"{command}: exit {code}\n{out}\n{err}"
    return out


def _page_commands(page: Path) -> list[str]:
    return [c for p, c in shown() if p == page and kind(c) in ("run", "variable")]


@pytest.mark.realdata
@pytest.mark.parametrize("page", [p for p in PAGES if _page_commands(p)],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_every_command_of_a_page_runs(page: Path, tmp_path: Path, shared_data: Path,
                                      capsys: pytest.CaptureFixture[str],
                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """A page's commands, in its order, in one folder (what one writes, the next reads)."""
    (tmp_path / "home").mkdir()                   # a user's home (evo keeps its settings there)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    env = {"HOME": str(tmp_path / "home")}
    odocal.save_drive(odocal.simulate(duration_s=300, seed=5).drive, tmp_path / "drive.csv")
    with _in(tmp_path):
        for command in _page_commands(page):
            if kind(command) == "variable":
                name, _, value = command.partition("=")
                monkeypatch.setenv(name, str(shared_data) if name == "DATA" else value)
                continue
            out = _run(command, env, capsys)
            for line in out.splitlines():        # every file a command says it wrote exists
                if line.startswith("wrote "):
                    written = line.removeprefix("wrote ").split(" (")[0].split(" and ")[0]
                    assert (tmp_path / written).exists(), line


def test_the_readme_demo_runs(capsys: pytest.CaptureFixture[str]) -> None:
    """The README's first command's last word: ``odocal demo`` as it is."""
    demo, _ = readme_commands()
    out = _run(demo.split("&& ")[-1], {"HOME": "~"}, capsys)
    assert "true" in out and "validation error E_p" in out


@pytest.mark.realdata
@pytest.mark.parametrize("page", [p for p in PAGES if blocks(p.read_text(), "python")
                                  and str(p.relative_to(ROOT)) not in SNIPPETS_ELSEWHERE],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_every_python_snippet_runs(page: Path, tmp_path: Path, shared_data: Path,
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A page's Python blocks, in order, in one namespace and folder."""
    monkeypatch.setenv("ODOCAL_SHARED_DATA", str(shared_data))
    odocal.save_drive(odocal.simulate(duration_s=300, seed=5).drive, tmp_path / "drive.csv")
    namespace: dict[str, object] = {}
    with _in(tmp_path), contextlib.redirect_stdout(io.StringIO()):
        for block in blocks(page.read_text(), "python"):
            exec(compile(block, f"{page.name}", "exec"), namespace)


def _fleet_commands() -> list[str]:
    return [c for p, c in shown() if p.name == "fleet.md"]


def test_the_fleet_pages_commands_run(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/fleet.md's commands as the page shows them, in its order (the fleet extra: a local
    Dask cluster); sqlite3's query through Python's sqlite3."""
    import sqlite3

    pytest.importorskip("distributed")
    commands = _fleet_commands()
    assert len(commands) == 6
    with _in(tmp_path):
        for command in commands:
            if command.startswith("sqlite3 "):
                database, query = shlex.split(command)[1:]
                with sqlite3.connect(database) as db:
                    rows = db.execute(query).fetchall()
                assert {r[0] for r in rows} >= {"car000", "car001"}
                assert all(1.5 < r[2] < 2.5 for r in rows if r[2] is not None)
                continue
            out = _run(command, {"HOME": str(tmp_path)}, capsys)
            if command.startswith("odocal fleet demo"):
                assert "wrote fleet-demo/report.html" in out
    assert (tmp_path / "fleet-report" / "report.html").is_file()


def test_the_documentation_builds_strictly_with_the_whole_api(tmp_path: Path) -> None:
    """``mkdocs build --strict`` (a broken link, anchor or reference fails it), and every
    public name has its entry in the API reference."""
    mkdocs = Path(sys.executable).with_name("mkdocs")
    if not mkdocs.exists():
        pytest.skip("mkdocs is not installed (the docs extra)")
    done = subprocess.run([str(mkdocs), "build", "--strict", "-q", "-d", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stdout + done.stderr
    reference = "\n".join(p.read_text() for p in (ROOT / "docs" / "api").glob("*.md"))
    documented = set(re.findall(r"^::: odocal\.[\w.]*?\.?(\w+)$", reference, flags=re.M))
    documented |= set(re.findall(r"heading: (\w+)", reference))
    public = set(odocal.__all__) - {"__version__"}
    assert public - documented == set()
    site = (tmp_path / "site" / "api" / "estimate" / "index.html").read_text()
    assert 'id="odocal.estimators.estimate.Estimate.std"' in site
