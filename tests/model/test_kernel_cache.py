"""The compiled kernels follow an edit to the model: their disk cache is keyed on every source
they inline, not only on the file that defines them (numba's own key)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import odocal
from odocal.model._jit import kernel_sources

PACKAGE = Path(odocal.__file__).parent

# Rolls a short drive out with its Jacobian through the compiled kernel and says whether the
# kernel came from the disk cache.
PROBE = """
import json, numpy as np
from odocal.model import compiled
from odocal.model.parameters import Inputs
k = 50
u = Inputs(n_rl=np.full((2, k), 5.0), n_rr=np.linspace(5.0, 5.5, 2 * k).reshape(2, k),
           beta=np.zeros((2, k)), a_y=np.full((2, k), 1.0))
poses, jac = compiled.rollout_with_jacobian(np.array([1.95, 0.001, 1.5, 0.001]), u,
                                            np.zeros((2, 3)), 0.025)
stats = compiled._jacobian_kernel.stats
print(json.dumps({"jac": jac.ravel().tolist(), "poses": poses.ravel().tolist(),
                  "hits": sum(stats.cache_hits.values()),
                  "misses": sum(stats.cache_misses.values())}))
"""


def _run(root: Path) -> dict[str, object]:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["PYTHONPATH"] = str(root)
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                          env=env, timeout=600, cwd=root)
    assert done.returncode == 0, done.stderr
    out: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    return out


def test_an_edit_to_the_step_reaches_the_compiled_kernels(tmp_path: Path) -> None:
    root = tmp_path / "src"
    shutil.copytree(PACKAGE, root / "odocal", ignore=shutil.ignore_patterns("__pycache__"))
    step = root / "odocal" / "model" / "step.py"
    original = step.read_text()

    first = _run(root)
    assert first["misses"] == 1 and first["hits"] == 0          # compiled, then cached
    again = _run(root)
    assert again["hits"] == 1 and again["misses"] == 0          # from the disk cache
    assert again["jac"] == first["jac"]

    # flip the sign of one Jacobian term in the step the kernel inlines
    edited = original.replace("out[1, p] = st * dv[p] + dx * dh",
                              "out[1, p] = st * dv[p] - dx * dh")
    assert edited != original
    step.write_text(edited)
    changed = _run(root)
    assert changed["misses"] == 1 and changed["hits"] == 0      # the edit is compiled
    assert changed["poses"] == first["poses"]                   # the rollout is untouched
    assert not np.allclose(changed["jac"], first["jac"])        # the Jacobian follows the edit

    step.write_text(original)
    back = _run(root)
    assert back["jac"] == first["jac"]


@pytest.mark.parametrize(("module", "kernel", "inlined"), [
    ("odocal.model.compiled", "_r_factor_kernel", {"model/compiled.py", "model/step.py"}),
    ("odocal.model.compiled", "_step_jacobian_kernel", {"model/compiled.py", "model/step.py"}),
    ("odocal.estimators.compensation.riccati", "_pdas",
     {"estimators/compensation/riccati.py"}),
    ("odocal.preprocess.fusion", "_ekf_rts", {"preprocess/fusion.py"}),
])
def test_each_kernel_is_keyed_on_the_sources_it_reaches(module: str, kernel: str,
                                                        inlined: set[str]) -> None:
    import importlib

    dispatcher = getattr(importlib.import_module(module), kernel)
    files = {p.relative_to(PACKAGE).as_posix() for p in kernel_sources(dispatcher.py_func)}
    assert inlined <= files
    assert all(not f.startswith("cli/") for f in files)
