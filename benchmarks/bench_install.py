"""The base install's footprint and ``import odocal``'s time (issue 39).

    python benchmarks/bench_install.py [--keep /tmp/base]

Makes a fresh virtual environment, installs this checkout into it as the README's first command
does (``pip install .``: the base install, no extra), and prints the site-packages size
(``du -sk``; the target is under 600 MB), the packages installed, whether any package of an
extra came along (numba, llvmlite, dask, distributed, bokeh, osqp must not), and the time of
``import odocal`` in that environment (the best of five fresh interpreters; the target is under
0.3 s), with the modules it loaded. Then the demo runs there, as a user's first command does.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXTRAS_ONLY = ("numba", "llvmlite", "dask", "distributed", "bokeh", "osqp", "pandas")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, help="make the environment here and keep it")
    args = parser.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="odocal-base-")) / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(folder)], check=True)
    python = folder / "bin" / "python"
    started = time.perf_counter()
    subprocess.run([str(python), "-m", "pip", "install", "-q", str(ROOT)], check=True)
    installed_s = time.perf_counter() - started
    site = next((folder / "lib").glob("python*/site-packages"))
    kb = int(subprocess.run(["du", "-sk", str(site)], capture_output=True, text=True,
                            check=True).stdout.split()[0])
    listed = subprocess.run([str(python), "-m", "pip", "list", "--format=freeze"],
                            capture_output=True, text=True, check=True).stdout.split()
    names = sorted(line.split("==")[0] for line in listed)
    extra = [n for n in names if n.lower() in EXTRAS_ONLY]
    print(f"pip install . into a fresh venv: {installed_s:.1f} s")
    print(f"site-packages: {kb / 1024:.0f} MB (target under 600 MB), {len(names)} packages")
    print("  " + " ".join(names))
    print(f"packages of an extra in the base install: {extra or 'none'}")
    code = ("import sys, time; t = time.perf_counter(); import odocal; "
            "print(time.perf_counter() - t, len(sys.modules), "
            "any(m in sys.modules for m in ('numpy', 'scipy', 'pyarrow', 'matplotlib')))")
    runs = [subprocess.run([str(python), "-c", code], capture_output=True, text=True,
                           check=True).stdout.split() for _ in range(5)]
    best = min(runs, key=lambda r: float(r[0]))
    print(f"import odocal: {float(best[0]):.3f} s best of 5 (target under 0.3 s), "
          f"{best[1]} modules loaded, numpy/scipy/pyarrow/matplotlib loaded: {best[2]}")
    with tempfile.TemporaryDirectory() as work:
        started = time.perf_counter()
        demo = subprocess.run([str(folder / "bin" / "odocal"), "demo"], cwd=work,
                              capture_output=True, text=True)
        print(f"odocal demo in the base install: exit {demo.returncode}, "
              f"{time.perf_counter() - started:.1f} s")
    if args.keep is None:
        print(f"(the environment is in {folder}; --keep to choose where)")


if __name__ == "__main__":
    main()
