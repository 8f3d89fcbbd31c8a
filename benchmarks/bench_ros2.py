"""``odocal ros2`` with DDS in the loop: message rate, latency and memory (issue 29).

    python benchmarks/bench_ros2.py [--factors 25,50,100] [--sweep-minutes 10] [--hour-factor 50]
                                    [--profile]

Three processes on this machine's private ROS 2 domain (discovery on localhost only):

* the **node**, ``odocal ros2`` as a user starts it (``use_sim_time``), pinned to one core;
* a **player** on the other core publishing a simulated drive as a vehicle does: wheel joint
  velocities (``sensor_msgs/JointState``) and an IMU at 100 Hz, the reference pose
  (``nav_msgs/Odometry``) at 50 Hz, and ``/clock``, paced at a real-time factor;
* a **listener** receiving the node's calibrated wheel odometry (one per wheel message).

Printed per real-time factor: the messages the node took per second, how many of its outputs
arrived (a shortfall means it fell behind and DDS dropped input), the 50th/99th percentile and
largest latency from a wheel message's publication to the arrival of the odometry computed from
it (the published estimate), how many calibration updates reached ``/diagnostics``, and the
node's resident memory (peak, and at the end). Then an hour of driving at ``--hour-factor``:
the same, with the node's memory after the hour. ``--profile`` runs the node under cProfile for
the first sweep factor and prints where its time goes.
"""

from __future__ import annotations

import argparse
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
WHEEL_HZ, POSE_EVERY = 100.0, 2               # wheels and IMU at 100 Hz, the pose at 50 Hz
START_S = 1000.0
QOS_DEPTH = [1000]                            # the node's input queues (--qos-depth)


def _env(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               NUMBA_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return env


def _rss_kb(pid: int, field: str) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


# ----------------------------------------------------------------------------------- player

class _Template:
    """A message serialized once; stamps and values patched into its CDR bytes per message."""

    def __init__(self, msg: Any, fields: dict[str, Any]) -> None:
        from rclpy.serialization import serialize_message

        self.data = bytearray(serialize_message(msg))
        self.offsets: dict[str, tuple[int, str]] = {}
        for name, (marker, fmt) in fields.items():
            packed = struct.pack("<" + fmt, marker)
            at = self.data.find(packed)
            assert at >= 0 and self.data.find(packed, at + 1) < 0, name
            self.offsets[name] = (at, "<" + fmt)

    def make(self, **values: Any) -> bytes:
        for name, value in values.items():
            at, fmt = self.offsets[name]
            struct.pack_into(fmt, self.data, at, value)
        return bytes(self.data)


def _templates() -> dict[str, _Template]:
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, JointState

    sec, nsec = (1_111_111_111, "i"), (333_333_333, "I")
    joint = JointState(name=["rear_left_wheel_joint", "rear_right_wheel_joint"],
                       velocity=[1.25e-300, 2.5e-300])
    joint.header.stamp.sec, joint.header.stamp.nanosec = sec[0], nsec[0]
    imu = Imu()
    imu.header.stamp.sec, imu.header.stamp.nanosec = sec[0], nsec[0]
    imu.angular_velocity.z, imu.linear_acceleration.y = 3.5e-300, 4.5e-300
    imu.linear_acceleration.z = 9.81
    pose = Odometry()
    pose.header.stamp.sec, pose.header.stamp.nanosec = sec[0], nsec[0]
    p = pose.pose.pose
    p.position.x, p.position.y, p.orientation.z, p.orientation.w = 5.5e-300, 6.5e-300, \
        7.5e-300, 8.5e-300
    clock = Clock()
    clock.clock.sec, clock.clock.nanosec = sec[0], nsec[0]
    return {
        "wheels": _Template(joint, {"sec": sec, "nsec": nsec, "l": (1.25e-300, "d"),
                                    "r": (2.5e-300, "d")}),
        "imu": _Template(imu, {"sec": sec, "nsec": nsec, "w": (3.5e-300, "d"),
                               "a": (4.5e-300, "d")}),
        "pose": _Template(pose, {"sec": sec, "nsec": nsec, "x": (5.5e-300, "d"),
                                 "y": (6.5e-300, "d"), "qz": (7.5e-300, "d"),
                                 "qw": (8.5e-300, "d")}),
        "clock": _Template(clock, {"sec": sec, "nsec": nsec}),
    }


def player(drive_path: str, factor: float, out: str) -> None:
    """Publish the drive paced at ``factor`` times real time; record each wheel message's
    publication time (CLOCK_MONOTONIC, shared by the processes)."""
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, JointState

    data = np.load(drive_path)
    t, n_rl, n_rr = data["t"], data["n_rl"], data["n_rr"]
    a_y, yaw, x, y, psi = data["a_y"], data["yaw_rate"], data["x"], data["y"], data["psi"]
    rclpy.init(args=["--ros-args", "--disable-external-lib-logs"])
    node = Node("bench_player")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {"wheels": node.create_publisher(JointState, "/bench/joint_states", qos),
            "imu": node.create_publisher(Imu, "/bench/imu", qos),
            "pose": node.create_publisher(Odometry, "/bench/pose", qos),
            "clock": node.create_publisher(Clock, "/clock", 10)}
    deadline = time.monotonic() + 30
    while pubs["wheels"].get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)                                     # every endpoint matched
    tpl = _templates()
    sent = np.zeros(t.size)
    two_pi = 2 * np.pi
    wall0 = time.monotonic()
    next_clock = 0.0
    for k in range(t.size):
        due = wall0 + t[k] / factor
        while True:
            now = time.monotonic()
            if now >= due:
                break
            time.sleep(min(due - now, 0.001))
        stamp = START_S + float(t[k])
        sec = int(stamp)
        nsec = round((stamp - sec) * 1e9)
        if t[k] >= next_clock:
            pubs["clock"].publish(tpl["clock"].make(sec=sec, nsec=nsec))
            next_clock = t[k] + 0.1
        pubs["imu"].publish(tpl["imu"].make(sec=sec, nsec=nsec, w=float(yaw[k]),
                                            a=float(a_y[k])))
        if k % POSE_EVERY == 0:
            half = 0.5 * float(psi[k])
            pubs["pose"].publish(tpl["pose"].make(sec=sec, nsec=nsec, x=float(x[k]),
                                                  y=float(y[k]), qz=np.sin(half),
                                                  qw=np.cos(half)))
        sent[k] = time.monotonic()
        pubs["wheels"].publish(tpl["wheels"].make(sec=sec, nsec=nsec,
                                                  l=float(n_rl[k] * two_pi),
                                                  r=float(n_rr[k] * two_pi)))
    np.save(out, sent)
    time.sleep(0.5)
    node.destroy_node()
    rclpy.shutdown()


# --------------------------------------------------------------------------------- listener

def listener(out: str, n: int) -> None:
    """Receive the node's odometry (and diagnostics) until told to stop (SIGINT)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    rclpy.init(args=["--ros-args", "--disable-external-lib-logs"])
    node = Node("bench_listener")
    received = np.full(n, np.nan)
    updates: list[str] = []

    def on_odom(msg: Any) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 - START_S
        k = round(stamp * WHEEL_HZ)
        if 0 <= k < n:
            received[k] = time.monotonic()

    def on_diag(msg: Any) -> None:
        for s in msg.status:
            if s.name.startswith(NODE) and "calibration" in s.name:
                updates.append(next((kv.value for kv in s.values if kv.key == "updates"), ""))

    node.create_subscription(Odometry, f"/{NODE}/odometry", on_odom,
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)
    executor = EventsExecutor()
    executor.add_node(node)
    Path(out + ".ready").write_text("")
    try:
        while True:
            executor.spin_once(timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    np.save(out, received)
    Path(out + ".json").write_text(json.dumps({"updates": sorted(set(updates) - {""},
                                                                  key=int)}))


# ------------------------------------------------------------------------------------- runs

def _drive(minutes: float, folder: Path) -> tuple[Path, int]:
    import odocal

    sim = odocal.simulate(duration_s=minutes * 60.0, seed=5, noise="realistic",
                          t_s=1.0 / WHEEL_HZ)
    d = sim.drive
    path = folder / f"drive_{minutes:g}.npz"
    np.savez(path, t=d.t, n_rl=d.n_rl, n_rr=d.n_rr, a_y=d.a_y, yaw_rate=d.yaw_rate, x=d.x,
             y=d.y, psi=d.psi)
    return path, d.n_samples


def run(drive: Path, n: int, factor: float, folder: Path, domain: int, *,
        profile: bool = False) -> dict[str, Any]:
    env = _env(domain)
    cores = sorted(os.sched_getaffinity(0))
    node_core, other = {cores[-1]}, set(cores[:-1]) or {cores[0]}
    tag = f"{factor:g}_{n}"
    prof = folder / f"node_{tag}.prof"
    python = [sys.executable] + (["-m", "cProfile", "-o", str(prof)] if profile else [])
    node_cmd = [*python, "-m", "odocal", "ros2", "--ros-args", "-r", f"__node:={NODE}",
                "-p", "use_sim_time:=true", "-p", "wheel_topic:=/bench/joint_states",
                "-p", "imu_topic:=/bench/imu", "-p", "pose_topic:=/bench/pose",
                "-p", f"qos_depth:={QOS_DEPTH[0]}", "--disable-external-lib-logs"]
    err = open(folder / f"node_{tag}.err", "w")
    node = subprocess.Popen(node_cmd, env=env, cwd=ROOT, stderr=err, stdout=subprocess.DEVNULL,
                            preexec_fn=lambda: os.sched_setaffinity(0, node_core))
    out = str(folder / f"recv_{tag}.npy")
    lst = subprocess.Popen([sys.executable, __file__, "--role", "listener", "--out", out,
                            "--n", str(n)], env=env,
                           preexec_fn=lambda: os.sched_setaffinity(0, other))
    while not Path(out + ".ready").exists():
        time.sleep(0.05)
    sent_path = str(folder / f"sent_{tag}.npy")
    started = time.monotonic()
    subprocess.run([sys.executable, __file__, "--role", "player", "--drive", str(drive),
                    "--factor", str(factor), "--out", sent_path], env=env, check=True,
                   preexec_fn=lambda: os.sched_setaffinity(0, other))
    played = time.monotonic() - started
    # the node takes what is still queued, then: memory, then Ctrl-C (final estimate)
    deadline = time.monotonic() + 120
    received = None
    while time.monotonic() < deadline:
        time.sleep(1.0)
        if node.poll() is not None:
            break
        cpu_now = Path(f"/proc/{node.pid}/stat").read_text().split()
        busy = int(cpu_now[13]) + int(cpu_now[14])
        time.sleep(1.0)
        cpu_later = Path(f"/proc/{node.pid}/stat").read_text().split()
        if int(cpu_later[13]) + int(cpu_later[14]) - busy < 5:      # idle: caught up
            break
    rss_end, rss_peak = _rss_kb(node.pid, "VmRSS"), _rss_kb(node.pid, "VmHWM")
    node.send_signal(signal.SIGINT)
    node.wait(timeout=120)
    err.close()
    lst.send_signal(signal.SIGINT)
    lst.wait(timeout=60)
    sent = np.load(sent_path)
    received = np.load(out)
    meta = json.loads(Path(out + ".json").read_text())
    ok = np.isfinite(received)
    latency = (received[ok] - sent[ok]) * 1000.0
    sim_s = n / WHEEL_HZ
    messages = n * 2 + (n + POSE_EVERY - 1) // POSE_EVERY
    result = {"factor": factor, "sim_s": sim_s, "played_s": played,
              "achieved_factor": sim_s / played, "messages": messages,
              "messages_per_s": messages / played, "outputs": int(ok.sum()), "inputs": n,
              "p50_ms": float(np.percentile(latency, 50)) if latency.size else np.nan,
              "p99_ms": float(np.percentile(latency, 99)) if latency.size else np.nan,
              "max_ms": float(latency.max()) if latency.size else np.nan,
              "updates": len(meta["updates"]), "rss_end_mb": rss_end / 1024,
              "lost_at_s": [round(float(k) / WHEEL_HZ, 1) for k in np.flatnonzero(~ok)[:3]],
              "rss_peak_mb": rss_peak / 1024}
    if profile:
        import pstats

        stats = pstats.Stats(str(prof))
        stats.sort_stats("tottime").print_stats(18)
    return result


def _row(r: dict[str, Any]) -> str:
    return (f"{r['factor']:>6g}x {r['sim_s'] / 60:>7.1f} {r['achieved_factor']:>8.1f}x "
            f"{r['messages_per_s']:>9.0f} {r['outputs']:>8d}/{r['inputs']:<8d} "
            f"{r['p50_ms']:>7.2f} {r['p99_ms']:>8.2f} {r['max_ms']:>8.1f} {r['updates']:>7d} "
            f"{r['rss_peak_mb']:>8.0f} {r['rss_end_mb']:>8.0f}"
            + (f"  (first lost at {r['lost_at_s']} s of the drive)" if r["lost_at_s"] else ""))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--role", choices=("bench", "player", "listener"), default="bench")
    ap.add_argument("--drive"), ap.add_argument("--out"), ap.add_argument("--n", type=int)
    ap.add_argument("--factor", type=float)
    ap.add_argument("--factors", default="25,50,100")
    ap.add_argument("--sweep-minutes", type=float, default=10.0)
    ap.add_argument("--hour-factor", type=float, default=50.0)
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--qos-depth", type=int, default=1000)
    args = ap.parse_args()
    QOS_DEPTH[0] = args.qos_depth
    if args.role == "player":
        player(args.drive, args.factor, args.out)
        return
    if args.role == "listener":
        listener(args.out, args.n)
        return
    domain = random.SystemRandom().randint(1, 101)
    print(f"ROS 2 domain {domain} (localhost discovery); qos_depth {args.qos_depth}; node "
          "pinned to core "
          f"{sorted(os.sched_getaffinity(0))[-1]}; cores {os.cpu_count()}, load "
          f"{os.getloadavg()[0]:.1f}")
    header = (f"{'factor':>7} {'sim min':>7} {'achieved':>9} {'msgs/s':>9} "
              f"{'outputs/inputs':>17} {'p50 ms':>7} {'p99 ms':>8} {'max ms':>8} "
              f"{'updates':>7} {'peak MB':>8} {'end MB':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        drive, n = _drive(args.sweep_minutes, folder)
        print(header)
        for i, factor in enumerate(float(f) for f in args.factors.split(",") if f):
            print(_row(run(drive, n, factor, folder, domain, profile=args.profile and i == 0)),
                  flush=True)
        if args.hours > 0:
            drive, n = _drive(args.hours * 60.0, folder)
            print(f"{args.hours:g} h of driving at {args.hour_factor:g}x:")
            print(header)
            print(_row(run(drive, n, args.hour_factor, folder, domain)), flush=True)


if __name__ == "__main__":
    main()
