"""The segment methods' Jacobians on numpy against the step run one number at a time.

The reference below is the loop the compiled kernels ran before (issue 30): the model step of
:mod:`odocal.model.step` on single numbers, ``J+ = A_k J + B_k`` step by step, the segment's
``[sqrt(W) J | sqrt(W) R]`` written out row by row. The vectorised versions must agree with it
to rounding; finite differences check both against the rollout (tests/model/test_model.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from odocal.model import step
from odocal.model.jacobians import (
    CHUNK_STEPS,
    linearised_rollout,
    rollout_with_jacobian,
    segment_r_factors,
    step_jacobians,
)
from odocal.model.kinematics import rollout
from odocal.model.parameters import PARAMETERS, Inputs

THETA = np.array([1.95, -0.002, 1.53, 0.0008])
T_S = 0.025
WEIGHTS = np.array([1.0, 2.0, 1600.0])


def inputs(rng: np.random.Generator, n: int, k: int) -> Inputs:
    base = rng.uniform(2.0, 7.0, (n, 1))
    return Inputs(n_rl=base + 0.3 * rng.standard_normal((n, k)),
                  n_rr=base + 0.3 * rng.standard_normal((n, k)),
                  beta=0.02 * rng.standard_normal((n, k)), a_y=rng.uniform(-3.0, 3.0, (n, k)))


def one_by_one(theta: np.ndarray, u: Inputs, ref: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Poses, Jacobians, [sqrt(W) J | sqrt(W) R] and the step Jacobians A, B of each segment,
    one step at a time from ref[:, 0]."""
    n, k = u.n_rl.shape
    poses = np.zeros((n, k + 1, 3))
    jac = np.zeros((n, k + 1, 3, PARAMETERS))
    mat = np.zeros((n, 3 * k, PARAMETERS + 1))
    a = np.zeros((n, k, 3, 3))
    b = np.zeros((n, k, 3, 2))
    sqrt_w = np.sqrt(WEIGHTS)
    d = np.zeros((3, 2 + PARAMETERS))
    for s in range(n):
        x, y, psi = ref[s, 0]
        poses[s, 0] = x, y, psi
        for i in range(k):
            args = (u.n_rl[s, i], u.n_rr[s, i], u.a_y[s, i])
            v, w, c_rl, c_rr = step.body(theta, *args)
            dx, dy, dpsi, ct, st = step.increment(psi, v, w, u.beta[s, i], T_S)
            step.increment_derivatives(theta, *args, v, w, c_rl, c_rr, dx, dy, ct, st, T_S, d)
            jpsi = jac[s, i, 2].copy()
            jac[s, i + 1, 0] = jac[s, i, 0] - dy * jpsi + d[0, 2:]
            jac[s, i + 1, 1] = jac[s, i, 1] + dx * jpsi + d[1, 2:]
            jac[s, i + 1, 2] = jpsi + d[2, 2:]
            a[s, i] = np.eye(3)
            a[s, i, 0, 2], a[s, i, 1, 2] = -dy, dx
            b[s, i] = d[:, :2]
            x, y, psi = x + dx, y + dy, psi + dpsi
            poses[s, i + 1] = x, y, psi
            residual = ref[s, i + 1] - poses[s, i + 1]
            residual[2] = step.wrap(residual[2])
            for c in range(3):
                mat[s, 3 * i + c, :PARAMETERS] = sqrt_w[c] * jac[s, i + 1, c]
                mat[s, 3 * i + c, PARAMETERS] = sqrt_w[c] * residual[c]
    return poses, jac, mat, a, b


Case = tuple[Inputs, np.ndarray, tuple[np.ndarray, ...]]


@pytest.fixture(scope="module")
def case() -> Case:
    rng = np.random.default_rng(7)
    u = inputs(rng, 3, 80)
    start = rng.standard_normal((3, 3))
    ref = rollout(THETA * [1.01, 1.0, 0.98, 1.0], u, start, T_S)
    ref += 0.05 * rng.standard_normal(ref.shape)
    ref[:, 0] = start
    ref[1, 40:, 2] += 2 * np.pi                     # a heading that went once round: wrapped
    return u, ref, one_by_one(THETA, u, ref)


def test_rollout_and_jacobian_agree_with_the_step_one_at_a_time(case: Case) -> None:
    u, ref, (poses, jac, _, a, b) = case
    got_poses, got_jac = rollout_with_jacobian(THETA, u, ref[:, 0], T_S)
    np.testing.assert_allclose(got_poses, poses, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(got_jac, jac, rtol=1e-12, atol=1e-12 * np.abs(jac).max())
    lin = step_jacobians(THETA, u, poses, T_S)
    np.testing.assert_allclose(lin.A, a, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(lin.B, b, rtol=1e-13, atol=1e-13)
    both_poses, both = linearised_rollout(THETA, u, ref[:, 0], T_S)
    np.testing.assert_allclose(both_poses, poses, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(both.A, a, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(both.B, b, rtol=1e-12, atol=1e-12)


def test_r_factors_agree_with_the_problem_written_out(case: Case) -> None:
    """R^T R is the Gram matrix of [sqrt(W) J | sqrt(W) R] (the signs of R's rows are
    LAPACK's), and the statistics are those of the residuals."""
    u, ref, (_, _, mat, _, _) = case
    r, stats = segment_r_factors(THETA, u, ref, T_S, WEIGHTS)
    gram = np.einsum("nki,nkj->nij", mat, mat)
    np.testing.assert_allclose(np.einsum("nki,nkj->nij", r, r), gram, rtol=1e-10,
                               atol=1e-12 * np.abs(gram).max())
    assert np.allclose(np.tril(r, -1), 0.0)
    res = mat[..., PARAMETERS].reshape(3, -1, 3)             # weighted, (N, K, channel)
    np.testing.assert_allclose(stats[:, 0], (res ** 2).sum(axis=(1, 2)), rtol=1e-12)
    np.testing.assert_allclose(stats[:, 1:4], (res ** 2 / WEIGHTS).sum(axis=1), rtol=1e-12)
    centred = res - res.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(stats[:, 4], (centred[:, 1:] * centred[:, :-1]).sum(axis=(1, 2)),
                               rtol=1e-10)
    assert abs(stats[1, 3] - stats[0, 3]) < 10.0            # the turn round is wrapped away


def test_chunks_do_not_change_the_factors() -> None:
    """Segments are taken a chunk at a time: more segments than a chunk holds give each
    segment's factor as alone."""
    rng = np.random.default_rng(3)
    k = 40
    n = CHUNK_STEPS // k + 3
    u = inputs(rng, n, k)
    ref = rollout(THETA, u, rng.standard_normal((n, 3)), T_S) + 0.01
    r, stats = segment_r_factors(THETA, u, ref, T_S, WEIGHTS)
    last = Inputs(*(getattr(u, f)[-2:] for f in ("n_rl", "n_rr", "beta", "a_y")))
    r_last, stats_last = segment_r_factors(THETA, last, ref[-2:], T_S, WEIGHTS)
    np.testing.assert_array_equal(stats[-2:], stats_last)
    np.testing.assert_array_equal(np.abs(r[-2:]), np.abs(r_last))
