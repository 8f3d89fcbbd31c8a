"""Fleets whose drives lie in an object store: throughput from the bucket against local files.

    python benchmarks/bench_fleet_remote.py [--vehicles 4] [--drives 6] [--duration 600]
        [--long 3600] [--workers 2]

An S3 API (moto's server, ``moto_server``, on a free loopback port; ``pip install -e
'.[test]'``) holds a simulated fleet of ``--vehicles`` x ``--drives`` drives of ``--duration`` s,
uploaded with its catalog. The fleet is calibrated twice on a fresh embedded Dask cluster of
``--workers`` single-threaded worker processes: from the local files, and from the bucket (the
catalog itself an object; each worker reads its own objects). Printed per run: wall time, drives
per minute, bytes each drive read from the store (measured by the workers), the workers' peak
memory (RSS), and whether both runs stored the same estimates to the last digit; then the rerun
from the bucket (nothing read: the store knows each object's version), and the same two runs on
``--vehicles`` drives of ``--long`` s, whose objects are larger: a worker's peak memory from the
bucket must stay near its peak from local files (objects are copied in 8 MiB chunks, never held
whole).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from odocal.fleet.engine import calibrate_fleet, dask_client
from odocal.fleet.simulate import simulate_fleet
from odocal.fleet.store import open_store


def _worker_rss_mb(client: Any) -> list[float]:
    def rss() -> float:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    return sorted(client.run(rss).values())


@contextlib.contextmanager
def s3_endpoint() -> Iterator[str]:
    """moto's S3 server on a free loopback port, its endpoint in this process's environment
    (which the worker processes inherit)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    server = shutil.which("moto_server", path=str(Path(sys.executable).parent)) or "moto_server"
    proc = subprocess.Popen([server, "-H", "127.0.0.1", "-p", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(400):
            with contextlib.suppress(OSError):
                socket.create_connection(("127.0.0.1", port), 0.2).close()
                break
            time.sleep(0.05)
        os.environ.update(AWS_ACCESS_KEY_ID="bench", AWS_SECRET_ACCESS_KEY="bench",
                          AWS_DEFAULT_REGION="us-east-1",
                          AWS_ENDPOINT_URL=f"http://127.0.0.1:{port}")
        yield os.environ["AWS_ENDPOINT_URL"]
    finally:
        proc.terminate()
        proc.wait(10)


def _upload(root: Path, bucket: str, prefix: str) -> int:
    import boto3

    s3 = boto3.client("s3", endpoint_url=os.environ["AWS_ENDPOINT_URL"])
    with contextlib.suppress(Exception):
        s3.create_bucket(Bucket=bucket)
    total = 0
    for path in sorted(root.rglob("*")):
        if path.is_file():
            s3.upload_file(str(path), bucket, f"{prefix}/{path.relative_to(root).as_posix()}")
            total += path.stat().st_size
    return total


def _answers(store: Path) -> dict[tuple[str, str], tuple[Any, ...]]:
    with open_store(store, create=False) as db:
        return {(r["vehicle"], r["time"]): (r["c_e"], r["c_d"], r["t_r"], r["d"], r["c_e_std"],
                                            r["status"]) for r in db.drives()}


def _run(catalog: Path | str, store: Path, workers: int, warm: Path, label: str,
         files: int) -> tuple[dict[tuple[str, str], tuple[Any, ...]], float]:
    with dask_client(workers=workers) as client:
        calibrate_fleet(warm, store.with_name(store.stem + "-warm.db"), client=client)
        started = time.perf_counter()
        run = calibrate_fleet(catalog, store, client=client)
        wall = time.perf_counter() - started
        memory = _worker_rss_mb(client)
        again_started = time.perf_counter()
        again = calibrate_fleet(catalog, store, client=client)
        again_wall = time.perf_counter() - again_started
    per_drive = run.bytes_read / max(run.calibrated, 1)
    rate = run.calibrated / wall * 60.0
    print(f"  {label:<13} {run.calibrated:>3} drives in {wall:6.1f} s = {rate:6.1f} drives/min; "
          f"read from the store {per_drive / 1e6:6.2f} MB/drive "
          f"(files {files / 1e6:.2f} MB/drive); "
          f"peak RSS per worker {', '.join(f'{m:.0f}' for m in memory)} MB; "
          f"{len(run.refused)} refused; rerun {again.calibrated} calibrated in "
          f"{again_wall:.1f} s")
    return _answers(store), rate


def compare(tmp: Path, name: str, vehicles: int, drives: int, duration: float,
            workers: int) -> None:
    started = time.perf_counter()
    fleet = simulate_fleet(tmp / name, vehicles=vehicles, drives=drives, duration_s=duration,
                           seed=200, plan="none")
    root = fleet.catalog.parent
    sizes = [p.stat().st_size for p in root.rglob("*.parquet")]
    size = sum(sizes) / len(sizes)
    uploaded = _upload(root, "bench", name)
    print(f"{fleet.drives} drives of {duration:.0f} s ({size / 1e6:.2f} MB each), uploaded "
          f"{uploaded / 1e6:.1f} MB, in {time.perf_counter() - started:.0f} s")
    warm = tmp / f"{name}-warm.csv"
    vehicle, path, when = fleet.catalog.read_text().splitlines()[1].split(",")[:3]
    warm.write_text(f"vehicle,path,time\n{vehicle},{root / path},{when}\n")   # imports, compiles
    local, local_rate = _run(fleet.catalog, tmp / f"{name}-local.db", workers, warm,
                             "local files", int(size))
    bucket, bucket_rate = _run(f"s3://bench/{name}/catalog.csv", tmp / f"{name}-s3.db",
                               workers, warm, "S3 bucket", int(size))
    print(f"  bucket/local throughput {bucket_rate / local_rate:.2f}; same estimates to the "
          f"last digit: {local == bucket} ({len(local)} drives)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--vehicles", type=int, default=4)
    parser.add_argument("--drives", type=int, default=6)
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--long", type=float, default=3600.0,
                        help="length of the drives of the memory comparison (0: skip it)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="odocal-bench-remote-") as tmp, s3_endpoint():
        compare(Path(tmp), "fleet", args.vehicles, args.drives, args.duration, args.workers)
        if args.long > 0:
            compare(Path(tmp), "long", args.vehicles, 2, args.long, args.workers)


if __name__ == "__main__":
    main()
