"""``odocal ros2`` with DDS in the loop: message rate, losses, latency and memory (issues 29, 41).

    python benchmarks/bench_ros2.py [--factors 25,50,100] [--sweep-minutes 10]
                                    [--hour-factor 100] [--hours 1] [--rate-hz 100]
                                    [--pose-every 2] [--profile] [--car]

Processes on this machine's private ROS 2 domain (discovery on localhost only):

* the **node**, ``odocal ros2`` as a user starts it (``use_sim_time``, best-effort inputs, the
  default ``qos_depth``), pinned to one core, and its calibrator's process (the default
  ``calibrator_process``: the pushes and estimates) moved to the other core;
* a **player** on the other core publishing a simulated drive as a vehicle does: wheel joint
  velocities (``sensor_msgs/JointState``) and an IMU at 100 Hz, the reference pose
  (``nav_msgs/Odometry``) at 50 Hz (``--rate-hz``, ``--pose-every``: issue 41's user published
  all three at 40 Hz), and ``/clock``, paced at a real-time factor; its messages are serialized
  a second of driving ahead, so that publishing is all it does on time;
* a **listener** on the player's core receiving the node's calibrated wheel odometry (one per
  wheel message; read from its bytes) and ``/diagnostics``.

First the **player's own limit**: the player unpaced (as fast as it can publish) with no node,
a sink on the node's core taking its messages and doing nothing else (so the writers have a
reader, as they do with the node), with the sink's CPU time per message: what taking a message
costs in rclpy and Fast DDS before any work. Then, per real-time factor: the factor the player
achieved, the messages per second, the messages the node took of those sent and those it found
missing by their stamps (its ``/diagnostics``: a shortfall means it fell behind and DDS dropped
input), how many of its outputs reached the listener (one per wheel message; reliable, on the
player's core), the 50th/99th percentile and largest latency from a wheel message's
publication to the arrival of the odometry computed from it,
the estimates the node took (its count in ``/diagnostics``: one every ``[online] update_s`` of
data and the final one) and how many of them the listener heard, the
node's CPU time per second of the run and its calibrator process's, the node's resident memory
(peak, at the end) and its calibrator's (peak). Then an hour
of driving at ``--hour-factor``. ``--profile`` runs the node under cProfile for the first
sweep factor and prints where its main thread's CPU time goes.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NODE = "odocal_bench"
#: The wheels' and IMU's rate (Hz) and every how many of their samples a pose comes
#: (--rate-hz, --pose-every: the defaults are a car's drivers, 100 Hz and 50 Hz).
RATE = {"hz": 100.0, "pose_every": 2}
#: --car: the four-wheel car (four wheel joints and the steering wheel's in one JointState, the
#: node started with [vehicle] model = "four_wheel" and steering_joint).
CAR = {"on": False}
CAR_JOINTS = ["front_left_wheel", "front_right_wheel", "rear_left_wheel", "rear_right_wheel",
              "steering_wheel"]
START_S = 1000.0
CHUNK = 100                                   # samples serialized at a time (1 s of driving)
TOPICS = ("/bench/joint_states", "/bench/imu", "/bench/pose")


def _env(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               NUMBA_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return env


def _children(pid: int) -> list[int]:
    """The processes ``pid`` started (its calibrator's)."""
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        try:
            out += [int(c) for c in task.read_text().split()]
        except OSError:
            pass
    return out


def _calibrator(node: Any, cores: set[int]) -> int | None:
    """The node's calibrator process (``calibrator_process``: it starts with the node),
    moved to ``cores``; None where the node has none within ten seconds."""
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and node.poll() is None:
        spawned = [c for c in _children(node.pid) if "spawn_main" in _cmdline(c)]
        if spawned:
            os.sched_setaffinity(spawned[0], cores)
            return spawned[0]
        time.sleep(0.05)
    return None


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _status_kb(pid: int, field: str) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _cpu_s(pid: int | None) -> float:
    """User and system CPU time of a process (all its threads), s (0 without one)."""
    if pid is None:
        return 0.0
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0.0
    fields = stat.rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


# ----------------------------------------------------------------------------------- player

class _Template:
    """A message serialized once; stamps and values written into copies of its CDR bytes, a
    block of messages at a time."""

    def __init__(self, msg: Any, fields: dict[str, Any]) -> None:
        from rclpy.serialization import serialize_message

        self.data = np.frombuffer(serialize_message(msg), dtype=np.uint8)
        self.offsets: dict[str, tuple[int, str]] = {}
        raw = self.data.tobytes()
        for name, (marker, fmt) in fields.items():
            packed = struct.pack("<" + fmt, marker)
            at = raw.find(packed)
            assert at >= 0 and raw.find(packed, at + 1) < 0, name
            self.offsets[name] = (at, "<" + {"i": "i4", "I": "u4", "d": "f8"}[fmt])

    def block(self, **columns: np.ndarray) -> list[bytes]:
        """One message per row of the columns (each an array of the block's length)."""
        n = len(next(iter(columns.values())))
        rows = np.tile(self.data, (n, 1))
        width = self.data.size
        for name, values in columns.items():
            at, dtype = self.offsets[name]
            view = np.ndarray((n,), dtype=dtype, buffer=rows, offset=at, strides=(width,))
            view[:] = values
        return [row.tobytes() for row in rows]


def _templates() -> dict[str, _Template]:
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, JointState

    sec, nsec = (1_111_111_111, "i"), (333_333_333, "I")
    joint = JointState(name=["rear_left_wheel_joint", "rear_right_wheel_joint"],
                       velocity=[1.25e-300, 2.5e-300])
    car = {"fl": (0.25e-300, "d"), "fr": (0.5e-300, "d"), "steer": (0.75e-300, "d")}
    if CAR["on"]:
        joint = JointState(name=CAR_JOINTS, velocity=[0.25e-300, 0.5e-300, 1.25e-300,
                                                      2.5e-300, 0.0],
                           position=[0.0, 0.0, 0.0, 0.0, 0.75e-300])
    joint.header.stamp.sec, joint.header.stamp.nanosec = sec[0], nsec[0]
    imu = Imu()
    imu.header.frame_id = "base_link"
    imu.header.stamp.sec, imu.header.stamp.nanosec = sec[0], nsec[0]
    imu.angular_velocity.z, imu.linear_acceleration.y = 3.5e-300, 4.5e-300
    imu.linear_acceleration.z = 9.81
    pose = Odometry()
    pose.header.frame_id, pose.child_frame_id = "map", "base_link"
    pose.header.stamp.sec, pose.header.stamp.nanosec = sec[0], nsec[0]
    p = pose.pose.pose
    p.position.x, p.position.y, p.orientation.z, p.orientation.w = 5.5e-300, 6.5e-300, \
        7.5e-300, 8.5e-300
    clock = Clock()
    clock.clock.sec, clock.clock.nanosec = sec[0], nsec[0]
    return {
        "wheels": _Template(joint, {"sec": sec, "nsec": nsec, "l": (1.25e-300, "d"),
                                    "r": (2.5e-300, "d"), **(car if CAR["on"] else {})}),
        "imu": _Template(imu, {"sec": sec, "nsec": nsec, "w": (3.5e-300, "d"),
                               "a": (4.5e-300, "d")}),
        "pose": _Template(pose, {"sec": sec, "nsec": nsec, "x": (5.5e-300, "d"),
                                 "y": (6.5e-300, "d"), "qz": (7.5e-300, "d"),
                                 "qw": (8.5e-300, "d")}),
        "clock": _Template(clock, {"sec": sec, "nsec": nsec}),
    }


def _clock_every() -> int:
    """Every how many samples /clock is published (a tenth of a second)."""
    return max(round(0.1 * RATE["hz"]), 1)


def _blocks(data: Any, tpl: dict[str, _Template], lo: int, hi: int) -> dict[str, list[bytes]]:
    """The messages of samples lo..hi: wheels, imu, pose (every pose_every-th), clock (each
    tenth of a second)."""
    t = START_S + data["t"][lo:hi]
    sec = np.floor(t).astype(np.int64)
    nsec = np.round((t - sec) * 1e9).astype(np.int64)
    two_pi = 2 * np.pi
    ks = np.arange(lo, hi)
    pose = ks % RATE["pose_every"] == 0
    clock = ks % _clock_every() == 0
    half = 0.5 * data["psi"][lo:hi]
    car = ({"fl": data["n_fl"][lo:hi] * two_pi, "fr": data["n_fr"][lo:hi] * two_pi,
            "steer": data["steer"][lo:hi]} if CAR["on"] else {})
    return {
        "wheels": tpl["wheels"].block(sec=sec, nsec=nsec, l=data["n_rl"][lo:hi] * two_pi,
                                      r=data["n_rr"][lo:hi] * two_pi, **car),
        "imu": tpl["imu"].block(sec=sec, nsec=nsec, w=data["yaw_rate"][lo:hi],
                                a=data["a_y"][lo:hi]),
        "pose": tpl["pose"].block(sec=sec[pose], nsec=nsec[pose], x=data["x"][lo:hi][pose],
                                  y=data["y"][lo:hi][pose], qz=np.sin(half[pose]),
                                  qw=np.cos(half[pose])),
        "clock": tpl["clock"].block(sec=sec[clock], nsec=nsec[clock]),
    }


def player(drive_path: str, factor: float, out: str) -> None:
    """Publish the drive paced at ``factor`` times real time (0: as fast as it can); record
    each wheel message's publication time (CLOCK_MONOTONIC, shared by the processes)."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, JointState

    data = dict(np.load(drive_path))
    n = data["t"].size
    rclpy.init(args=["--ros-args", "--disable-external-lib-logs"])
    node = Node("bench_player")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {"wheels": node.create_publisher(JointState, TOPICS[0], qos),
            "imu": node.create_publisher(Imu, TOPICS[1], qos),
            "pose": node.create_publisher(Odometry, TOPICS[2], qos),
            "clock": node.create_publisher(Clock, "/clock", 10)}
    deadline = time.monotonic() + 30
    while min(p.get_subscription_count() for r, p in pubs.items() if r != "clock") == 0 \
            and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)                                     # every endpoint matched, both ways
    tpl = _templates()
    sent = np.zeros(n)
    wheels, imu, pose, clock = (pubs["wheels"].publish, pubs["imu"].publish,
                                pubs["pose"].publish, pubs["clock"].publish)
    block = _blocks(data, tpl, 0, min(CHUNK, n))
    every = _clock_every()
    Path(out + ".start").write_text("")                 # (the node's CPU is counted from here)
    wall0 = time.monotonic()
    monotonic, sleep = time.monotonic, time.sleep
    for lo in range(0, n, CHUNK):
        hi = min(lo + CHUNK, n)
        w, i, p, c = block["wheels"], block["imu"], block["pose"], block["clock"]
        for j in range(hi - lo):
            k = lo + j
            if factor > 0:
                due = wall0 + data["t"][k] / factor
                now = monotonic()
                while now < due:
                    sleep(min(due - now, 0.001))
                    now = monotonic()
            if k % every == 0:
                clock(c[j // every])
            imu(i[j])
            if k % RATE["pose_every"] == 0:
                pose(p[j // RATE["pose_every"]])
            sent[k] = monotonic()
            wheels(w[j])
        if hi < n:                                      # the next second, serialized now
            block = _blocks(data, tpl, hi, min(hi + CHUNK, n))
    np.save(out, sent)
    time.sleep(0.5)
    node.destroy_node()
    rclpy.shutdown()


# ------------------------------------------------------------------------ listener, sink

def listener(out: str, n: int) -> None:
    """Receive the node's odometry (its stamps, from the bytes) and diagnostics until told to
    stop (SIGINT)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    rclpy.init(args=["--ros-args", "--disable-external-lib-logs"],
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = Node("bench_listener")
    received = np.full(n, np.nan)
    updates: set[str] = set()
    last: dict[str, str] = {}
    stamp = struct.Struct("<iI")
    monotonic = time.monotonic

    def on_odom(data: bytes) -> None:
        sec, nsec = stamp.unpack_from(data, 4)
        k = round((sec - START_S + nsec * 1e-9) * RATE["hz"])
        if 0 <= k < n:
            received[k] = monotonic()

    def on_diag(msg: Any) -> None:
        for s in msg.status:
            if s.name.startswith(NODE) and "calibration" in s.name:
                values = {kv.key: kv.value for kv in s.values}
                updates.add(values.get("updates", ""))
                last.clear()
                last.update(values)

    node.create_subscription(Odometry, f"/{NODE}/odometry", on_odom,
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
                             raw=True)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)
    executor = EventsExecutor()
    executor.add_node(node)
    stop: list[int] = []
    signal.signal(signal.SIGINT, lambda s, f: stop.append(s))
    signal.signal(signal.SIGTERM, lambda s, f: stop.append(s))
    Path(out + ".ready").write_text("")
    while not stop:
        executor.spin_once(timeout_sec=0.1)
    np.save(out, received)
    Path(out + ".json").write_text(json.dumps({"updates": sorted(updates - {""}, key=int),
                                               "last": last}))


def sink(out: str) -> None:
    """Take the player's messages and count them (raw, best effort: what the node's readers
    are), until told to stop."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, JointState

    rclpy.init(args=["--ros-args", "--disable-external-lib-logs"],
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = Node("bench_sink")
    counts = [0, 0, 0]
    qos = QoSProfile(depth=5000, reliability=ReliabilityPolicy.BEST_EFFORT)
    for i, (kind, topic) in enumerate(zip((JointState, Imu, Odometry), TOPICS, strict=True)):
        node.create_subscription(kind, topic, lambda m, i=i: counts.__setitem__(i, counts[i] + 1),
                                 qos, raw=True)
    executor = EventsExecutor()
    executor.add_node(node)
    stop: list[int] = []
    signal.signal(signal.SIGINT, lambda s, f: stop.append(s))
    Path(out + ".ready").write_text("")
    while not stop:
        executor.spin_once(timeout_sec=0.1)
    Path(out).write_text(json.dumps(counts))


# ------------------------------------------------------------------------------------- runs

def _drive(minutes: float, folder: Path) -> tuple[Path, int]:
    import odocal

    sim = odocal.simulate(duration_s=minutes * 60.0, seed=5, noise="realistic",
                          t_s=1.0 / RATE["hz"])
    if CAR["on"]:
        from odocal.sim.four_wheel import with_front_axle

        sim, _ = with_front_axle(sim)
    d = sim.drive
    path = folder / f"drive_{minutes:g}.npz"
    np.savez(path, t=d.t, n_rl=d.n_rl, n_rr=d.n_rr, a_y=d.a_y, yaw_rate=d.yaw_rate, x=d.x,
             y=d.y, psi=d.psi, **d.inputs)
    return path, d.n_samples


def _rate_args() -> list[str]:
    return ["--rate-hz", str(RATE["hz"]), "--pose-every", str(RATE["pose_every"]),
            *(["--car"] if CAR["on"] else [])]


def _cores() -> tuple[set[int], set[int]]:
    cores = sorted(os.sched_getaffinity(0))
    return {cores[-1]}, set(cores[:-1]) or {cores[0]}


def _start(argv: list[str], env: dict[str, str], cores: set[int], **kw: Any) -> Any:
    return subprocess.Popen(argv, env=env, preexec_fn=lambda: os.sched_setaffinity(0, cores),
                            **kw)


def _wait_ready(path: str) -> None:
    while not Path(path + ".ready").exists():
        time.sleep(0.05)


def _play(drive: Path, factor: float, out: str, env: dict[str, str], cores: set[int],
          node_pid: int | None = None) -> tuple[float, float]:
    """Run the player; the time it took to publish the drive (s), and the node's CPU time
    (s) when it began (0 without a node)."""
    proc = subprocess.Popen([sys.executable, __file__, "--role", "player", "--drive",
                             str(drive), "--factor", str(factor), "--out", out,
                             *_rate_args()], env=env,
                            preexec_fn=lambda: os.sched_setaffinity(0, cores))
    while not Path(out + ".start").exists() and proc.poll() is None:
        time.sleep(0.002)
    cpu0 = _cpu_s(node_pid) if node_pid is not None else 0.0
    if proc.wait() != 0:
        raise SystemExit(f"the player failed (exit {proc.returncode})")
    sent = np.load(out)
    return float(sent[-1] - sent[0]), cpu0


def player_limit(drive: Path, n: int, folder: Path, domain: int) -> dict[str, Any]:
    """The player unpaced, its messages taken by a sink on the node's core."""
    env = _env(domain)
    node_core, other = _cores()
    out = str(folder / "sink.json")
    sink_proc = _start([sys.executable, __file__, "--role", "sink", "--out", out], env,
                       node_core)
    _wait_ready(out)
    played, cpu0 = _play(drive, 0.0, str(folder / "sent_limit.npy"), env, other,
                         sink_proc.pid)
    _caught_up(sink_proc)
    cpu = _cpu_s(sink_proc.pid) - cpu0
    sink_proc.send_signal(signal.SIGINT)
    sink_proc.wait(timeout=60)
    counts = json.loads(Path(out).read_text())
    messages = n * 2 + (n + RATE["pose_every"] - 1) // RATE["pose_every"]
    return {"sim_s": n / RATE["hz"], "played_s": played, "factor": n / RATE["hz"] / played,
            "messages_per_s": messages / played, "taken": sum(counts), "messages": messages,
            "sink_us": cpu / max(sum(counts), 1) * 1e6}


def run(drive: Path, n: int, factor: float, folder: Path, domain: int, *,
        profile: bool = False) -> dict[str, Any]:
    env = _env(domain)
    node_core, other = _cores()
    tag = f"{factor:g}_{n}"
    prof = folder / f"node_{tag}.prof"
    python = [sys.executable] + (["-c", _PROFILED, str(prof)] if profile else ["-m", "odocal"])
    car: list[str] = []
    if CAR["on"]:
        (folder / "car.toml").write_text('[vehicle]\nmodel = "four_wheel"\n')
        car = ["--config", str(folder / "car.toml")]
    node_cmd = [*python, "ros2", *car, "--ros-args", "-r", f"__node:={NODE}",
                "-p", "use_sim_time:=true", "-p", f"wheel_topic:={TOPICS[0]}",
                "-p", f"imu_topic:={TOPICS[1]}", "-p", f"pose_topic:={TOPICS[2]}",
                *(["-p", "steering_joint:=steering_wheel"] if car else []),
                "--disable-external-lib-logs"]
    err = open(folder / f"node_{tag}.err", "w")
    node = _start(node_cmd, env, node_core, cwd=ROOT, stderr=err, stdout=subprocess.DEVNULL)
    calibrator = _calibrator(node, other)
    out = str(folder / f"recv_{tag}.npy")
    lst = _start([sys.executable, __file__, "--role", "listener", "--out", out, "--n", str(n),
                  *_rate_args()], env, other)
    _wait_ready(out)
    sent_path = str(folder / f"sent_{tag}.npy")
    calibrator0 = _cpu_s(calibrator)
    played, cpu0 = _play(drive, factor, sent_path, env, other, node.pid)
    _caught_up(node, calibrator)
    cpu = _cpu_s(node.pid) - cpu0
    calibrator_cpu = _cpu_s(calibrator) - calibrator0
    rss_end, rss_peak = _status_kb(node.pid, "VmRSS"), _status_kb(node.pid, "VmHWM")
    calibrator_peak = _status_kb(calibrator, "VmHWM") if calibrator is not None else 0
    signalled = time.monotonic()
    node.send_signal(signal.SIGINT)
    node.wait(timeout=120)
    exit_s = time.monotonic() - signalled
    err.close()
    lst.send_signal(signal.SIGINT)
    lst.wait(timeout=60)
    sent, received = np.load(sent_path), np.load(out)
    meta = json.loads(Path(out + ".json").read_text())
    ok = np.isfinite(received)
    latency = (received[ok] - sent[ok]) * 1000.0
    sim_s = n / RATE["hz"]
    messages = n * 2 + (n + RATE["pose_every"] - 1) // RATE["pose_every"]
    missing = sum(int(meta["last"].get(f"missing {t}", "-1")) for t in TOPICS)
    taken = sum(int(meta["last"].get(f"messages {t}", "-1")) for t in TOPICS)
    log = (folder / f"node_{tag}.err").read_text()
    result = {"factor": factor, "sim_s": sim_s, "played_s": played,
              "achieved_factor": sim_s / played, "messages": messages,
              "messages_per_s": messages / played, "outputs": int(ok.sum()), "inputs": n,
              "missing": missing, "taken": taken,
              "p50_ms": float(np.percentile(latency, 50)) if latency.size else np.nan,
              "p99_ms": float(np.percentile(latency, 99)) if latency.size else np.nan,
              "max_ms": float(latency.max()) if latency.size else np.nan,
              "heard_updates": len(meta["updates"]),
              "updates": max((int(u) for u in meta["updates"]), default=0),
              "cpu_share": cpu / played if played > 0 else np.nan,
              "calibrator_share": calibrator_cpu / played if played > 0 else np.nan,
              "rss_end_mb": rss_end / 1024, "rss_peak_mb": rss_peak / 1024,
              "calibrator_peak_mb": calibrator_peak / 1024,
              "exit_code": node.returncode, "exit_s": exit_s,
              "traceback": "Traceback" in log or "FATAL" in log,
              "lost_at_s": [round(float(k) / RATE["hz"], 1) for k in np.flatnonzero(~ok)[:3]]}
    if profile:
        import pstats

        pstats.Stats(str(prof)).sort_stats("tottime").print_stats(18)
    return result


#: ``python -c`` for the node under cProfile, timed by its main thread's CPU time (not the
#: wall clock, which counts the executor's waits and what the other threads and processes
#: took from its core): where the node's own thread spends its CPU.
_PROFILED = """
import cProfile, runpy, sys, time
out = sys.argv[1]
sys.argv = ["odocal", *sys.argv[2:]]
profile = cProfile.Profile(time.thread_time)
profile.enable()
try:
    runpy.run_module("odocal", run_name="__main__")
finally:
    profile.disable()
    profile.dump_stats(out)
"""


def _caught_up(node: Any, calibrator: int | None = None) -> None:
    """Wait until the node and its calibrator have taken what is still queued (idle for a
    second: less than 5% of a core), two minutes at most."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and node.poll() is None:
        busy = _cpu_s(node.pid) + _cpu_s(calibrator)
        time.sleep(1.0)
        if _cpu_s(node.pid) + _cpu_s(calibrator) - busy < 0.05:
            break


HEADER = (f"{'factor':>7} {'sim min':>7} {'achieved':>9} {'msgs/s':>9} "
          f"{'taken/sent':>15} {'missing':>7} {'outputs/inputs':>17} "
          f"{'p50 ms':>7} {'p99 ms':>8} {'max ms':>8} "
          f"{'estimates':>9} {'node CPU':>8} {'calib CPU':>9} {'peak MB':>8} {'end MB':>7} "
          f"{'calib MB':>8} {'exit':>10}")


def _row(r: dict[str, Any]) -> str:
    updates = f"{r['updates']} ({r['heard_updates']})"
    exit_text = f"{r['exit_code']} {r['exit_s']:.2f}s" + (" TB" if r["traceback"] else "")
    return (f"{r['factor']:>6g}x {r['sim_s'] / 60:>7.1f} {r['achieved_factor']:>8.1f}x "
            f"{r['messages_per_s']:>9.0f} {r['taken']:>7d}/{r['messages']:<7d} "
            f"{r['missing']:>7d} {r['outputs']:>8d}/{r['inputs']:<8d} "
            f"{r['p50_ms']:>7.2f} {r['p99_ms']:>8.2f} {r['max_ms']:>8.1f} "
            f"{updates:>9} {r['cpu_share'] * 100:>7.0f}% {r['calibrator_share'] * 100:>8.0f}% "
            f"{r['rss_peak_mb']:>8.0f} "
            f"{r['rss_end_mb']:>7.0f} {r['calibrator_peak_mb']:>8.0f} {exit_text:>10}"
            + (f"  (first lost at {r['lost_at_s']} s of the drive)" if r["lost_at_s"] else ""))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--role", choices=("bench", "player", "listener", "sink"),
                    default="bench")
    ap.add_argument("--drive"), ap.add_argument("--out"), ap.add_argument("--n", type=int)
    ap.add_argument("--factor", type=float)
    ap.add_argument("--factors", default="25,50,100")
    ap.add_argument("--sweep-minutes", type=float, default=10.0)
    ap.add_argument("--hour-factor", type=float, default=100.0)
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--rate-hz", type=float, default=100.0,
                    help="the wheels' and the IMU's rate (Hz; default 100)")
    ap.add_argument("--pose-every", type=int, default=2,
                    help="a pose every this many of their samples (default 2: 50 Hz)")
    ap.add_argument("--keep", metavar="DIR",
                    help="keep the run's files (the node's log, the drives) in a folder in DIR")
    ap.add_argument("--car", action="store_true",
                    help="the four-wheel car: four wheel joints and a steering joint")
    args = ap.parse_args()
    RATE["hz"], RATE["pose_every"] = args.rate_hz, args.pose_every
    CAR["on"] = args.car
    if args.role == "player":
        player(args.drive, args.factor, args.out)
        return
    if args.role == "listener":
        listener(args.out, args.n)
        return
    if args.role == "sink":
        sink(args.out)
        return
    domain = random.SystemRandom().randint(1, 101)
    node_core, _ = _cores()
    car = ("the four-wheel car (four wheels and the steering in each JointState); "
           if CAR["on"] else "")
    print(f"ROS 2 domain {domain} (localhost discovery); {car}wheels and IMU at "
          f"{RATE['hz']:g} Hz, the pose at {RATE['hz'] / RATE['pose_every']:g} Hz "
          f"({RATE['hz'] * (2 + 1 / RATE['pose_every']):g} messages per second of driving); "
          f"node pinned to core "
          f"{min(node_core)}; cores {os.cpu_count()}, load {os.getloadavg()[0]:.1f} "
          f"{os.getloadavg()[1]:.1f} {os.getloadavg()[2]:.1f} (1, 5, 15 min)")
    with (contextlib.nullcontext(tempfile.mkdtemp(dir=args.keep)) if args.keep
          else tempfile.TemporaryDirectory()) as tmp:
        folder = Path(tmp)
        drive, n = _drive(args.sweep_minutes, folder)
        limit = player_limit(drive, n, folder, domain)
        print(f"the player's own limit (unpaced, no node; a sink on the node's core takes its "
              f"messages): {limit['factor']:.1f}x real time, {limit['messages_per_s']:.0f} "
              f"messages/s ({limit['sim_s'] / 60:.1f} min of driving in "
              f"{limit['played_s']:.1f} s; the sink took {limit['taken']} of "
              f"{limit['messages']}, at {limit['sink_us']:.1f} us of its core's time each: "
              f"what taking a message costs before any work, "
              f"{limit['sink_us'] * RATE['hz'] * (2 + 1 / RATE['pose_every']) / 100:.0f}% of "
              "a core at 100x)", flush=True)
        print(HEADER)
        for i, factor in enumerate(float(f) for f in args.factors.split(",") if f):
            print(_row(run(drive, n, factor, folder, domain, profile=args.profile and i == 0)),
                  flush=True)
        if args.hours > 0:
            drive, n = _drive(args.hours * 60.0, folder)
            print(f"{args.hours:g} h of driving at {args.hour_factor:g}x:")
            print(HEADER)
            print(_row(run(drive, n, args.hour_factor, folder, domain)), flush=True)
        print(f"load at the end {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f} "
              f"{os.getloadavg()[2]:.1f}")


if __name__ == "__main__":
    main()
