"""An edit to the model reaches what runs it: the segment methods' Jacobians (numpy) at once, and
a compiled kernel that inlines the step through its disk cache, which is keyed on every source
it inlines, not only on the file that defines it (numba's own key)."""

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

# A kernel compiled with odocal's jit that inlines the model step (as a user's or a future
# model's kernel would), written beside the package copy; and the segment methods' Jacobian,
# which runs the step on numpy arrays (nothing of the model is compiled).
PROBE_KERNEL = """
import types
import numpy as np
from odocal.model import step
from odocal.model._jit import jit


def _compiled(function, **callees):
    env = dict(function.__globals__)
    env.update(callees)
    return jit(inline=True)(types.FunctionType(function.__code__, env, function.__name__))


_circumferences = _compiled(step.circumferences)
_body = _compiled(step.body, circumferences=_circumferences)
_increment = _compiled(step.increment)
_derivatives = _compiled(step.increment_derivatives)


@jit
def derivatives(th, n_rl, n_rr, a_y, out):
    for k in range(n_rl.shape[0]):
        v, w, c_rl, c_rr = _body(th, n_rl[k], n_rr[k], a_y[k])
        dx, dy, _, ct, st = _increment(0.1 * k, v, w, 0.0, 0.025)
        _derivatives(th, n_rl[k], n_rr[k], a_y[k], v, w, c_rl, c_rr, dx, dy, ct, st, 0.025,
                     out[k])
"""

PROBE = """
import json, numpy as np
import probe_kernel
from odocal.model import jacobians
from odocal.model.parameters import Inputs
k = 50
theta = np.array([1.95, 0.001, 1.5, 0.001])
u = Inputs(n_rl=np.full((2, k), 5.0), n_rr=np.linspace(5.0, 5.5, 2 * k).reshape(2, k),
           beta=np.zeros((2, k)), a_y=np.full((2, k), 1.0))
poses, jac = jacobians.rollout_with_jacobian(theta, u, np.zeros((2, 3)), 0.025)
out = np.zeros((k, 3, 6))
probe_kernel.derivatives(theta, u.n_rl[0], u.n_rr[0], u.a_y[0], out)
stats = probe_kernel.derivatives.stats
print(json.dumps({"jac": jac.ravel().tolist(), "poses": poses.ravel().tolist(),
                  "kernel": out.ravel().tolist(),
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
    (root / "probe_kernel.py").write_text(PROBE_KERNEL)
    step = root / "odocal" / "model" / "step.py"
    original = step.read_text()

    first = _run(root)
    assert first["misses"] == 1 and first["hits"] == 0          # compiled, then cached
    again = _run(root)
    assert again["hits"] == 1 and again["misses"] == 0          # from the disk cache
    assert again["jac"] == first["jac"] and again["kernel"] == first["kernel"]

    # flip the sign of one Jacobian term in the step the kernel inlines
    edited = original.replace("out[1, p] = st * dv[p] + dx * dh",
                              "out[1, p] = st * dv[p] - dx * dh")
    assert edited != original
    step.write_text(edited)
    changed = _run(root)
    assert changed["misses"] == 1 and changed["hits"] == 0      # the edit is compiled
    assert changed["poses"] == first["poses"]                   # the rollout is untouched
    assert not np.allclose(changed["jac"], first["jac"])        # the Jacobian follows the edit
    assert not np.allclose(changed["kernel"], first["kernel"])  # and so does the kernel

    step.write_text(original)
    back = _run(root)
    assert back["jac"] == first["jac"] and back["kernel"] == first["kernel"]


@pytest.mark.parametrize(("module", "kernel", "inlined"), [
    ("odocal.estimators.compensation.riccati", "_pdas",
     {"estimators/compensation/riccati.py"}),
    ("odocal.estimators.compensation.riccati", "_pdas_batch",
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
