"""METHOD 4: the compensation QP; the structured solver against OSQP on the same problems."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from odocal.data.segments import SegmentBatch, gather, identification_segments
from odocal.estimators.compensation import (
    FAILED,
    INFEASIBLE,
    SOLVED_FAST,
    SOLVED_KKT,
    SOLVED_OSQP,
    build_problem,
    compensate_batch,
    compensate_segment,
    solve_qp,
)
from odocal.estimators.compensation.problem import CompensationProblem
from odocal.estimators.compensation.reference import solve_osqp, sparse_qp
from odocal.estimators.compensation.riccati import solve_riccati
from odocal.estimators.compensation.structured import solve_structured
from odocal.model.parameters import Inputs
from odocal.settings import CompensateSettings, Settings
from odocal.sim.simulate import SimulatedDrive


@pytest.fixture(scope="module")
def batch(noisy_drive: SimulatedDrive) -> SegmentBatch:
    segs = identification_segments([noisy_drive.drive], Settings().segments)
    return gather([noisy_drive.drive], segs.subset(segs.selected))


def segment(batch: SegmentBatch, i: int) -> tuple[Inputs, np.ndarray]:
    u = batch.inputs
    return Inputs(u.n_rl[i], u.n_rr[i], u.beta[i], u.a_y[i]), batch.reference[i]


def problem(batch: SegmentBatch, i: int, theta: np.ndarray,
            settings: CompensateSettings | None = None) -> CompensationProblem:
    inputs, ref = segment(batch, i)
    return build_problem(theta, inputs, ref, batch.t_s, settings or CompensateSettings())


def kkt_violation(p: CompensationProblem, z: np.ndarray) -> float:
    """Largest violation of feasibility (equalities and bounds)."""
    qp = sparse_qp(p)
    az = qp.A @ z
    return float(max(np.max(qp.l - az), np.max(az - qp.u), 0.0))


THETAS = {
    "true": np.array([1.952, -0.0021, 1.527, 0.00076]),
    "step-1-like": np.array([1.9535, -0.0025, 1.545, 0.0006]),
    "datasheet": np.array([2.0, 0.0, 1.6, 0.0]),
}


@pytest.mark.parametrize("which", sorted(THETAS))
def test_structured_matches_osqp_on_many_segments(batch: SegmentBatch, which: str) -> None:
    theta = THETAS[which]
    active_seen = 0
    compared = 0
    for i in range(0, len(batch), max(1, len(batch) // 12)):
        p = problem(batch, i, theta)
        ours = solve_qp(p, CompensateSettings())
        ref = solve_osqp(p)
        assert ours.solved
        if not ref.solved:          # OSQP could not polish this one; nothing to compare
            continue
        compared += 1
        f_ours, f_ref = p.objective(ours.z), p.objective(ref.z)
        assert abs(f_ours - f_ref) <= 1e-6 * abs(f_ref)
        np.testing.assert_allclose(p.rates(ours.z), p.rates(ref.z), atol=1e-6)
        assert kkt_violation(p, ours.z) < 1e-9
        zr = ours.z.reshape(p.steps, 5)
        active_seen += int(np.sum(np.isclose(zr[:, :2], p.lower[:, :2], atol=1e-12)
                                  | np.isclose(zr[:, :2], p.upper[:, :2], atol=1e-12)))
    assert compared >= 10
    assert active_seen > 0          # the comparison covers active rate bounds


def test_active_state_bounds_take_the_banded_kkt_path(batch: SegmentBatch) -> None:
    # tight state bounds sit inside the optimum's tracking error: some of them bind
    settings = CompensateSettings(state_bounds=(0.3, 0.3, 0.02))
    kkt_cases = 0
    for i in range(0, len(batch), 6):
        p = problem(batch, i, THETAS["step-1-like"], settings)
        if solve_riccati(p).states_feasible:
            continue
        ours = solve_qp(p, settings)
        assert ours.status == SOLVED_KKT
        kkt_cases += 1
        ref = solve_osqp(p)
        assert ref.solved
        assert abs(p.objective(ours.z) - p.objective(ref.z)) <= 1e-6 * abs(p.objective(ref.z))
        dx = ours.z.reshape(p.steps, 5)[:, 2:]
        assert np.any(np.isclose(dx, p.lower[:, 2:], atol=1e-9)
                      | np.isclose(dx, p.upper[:, 2:], atol=1e-9))
        assert kkt_violation(p, ours.z) < 1e-9
    assert kkt_cases >= 3


def test_banded_kkt_solver_alone_matches(batch: SegmentBatch) -> None:
    p = problem(batch, 5, THETAS["step-1-like"])
    full = solve_structured(p)
    assert full.converged
    ref = solve_osqp(p)
    assert abs(p.objective(full.z) - p.objective(ref.z)) <= 1e-6 * abs(p.objective(ref.z))


def test_infeasible_problem_keeps_measured_rates(batch: SegmentBatch,
                                                 caplog: pytest.LogCaptureFixture) -> None:
    # +-0.1 % on the rates cannot absorb a 10 % circumference error inside +-0.5 m
    theta = np.array([2.15, 0.0, 1.6, 0.0])
    settings = CompensateSettings(state_bounds=(0.5, 0.5, 0.05), rate_bound=0.001)
    p = problem(batch, 3, theta, settings)
    assert solve_osqp(p).infeasible
    inputs, ref = segment(batch, 3)
    seg = compensate_segment(theta, inputs, ref, batch.t_s, settings)
    assert seg.status in (INFEASIBLE, FAILED) and not seg.solved
    np.testing.assert_array_equal(seg.rates[:, 0], inputs.n_rl)
    with caplog.at_level(logging.WARNING, logger="odocal.estimators.compensation"):
        out = compensate_batch(batch.take(slice(3, 5)), theta[None, :], settings)
    assert out.fell_back.all()
    assert "keep their measured wheel rates" in caplog.text
    np.testing.assert_array_equal(out.n_rl, batch.inputs.n_rl[3:5])


def test_noise_free_compensation_with_true_theta_stays_close(clean_drive: SimulatedDrive) -> None:
    segs = identification_segments([clean_drive.drive], Settings().segments)
    b = gather([clean_drive.drive], segs.subset(segs.selected)).take(slice(0, 4))
    out = compensate_batch(b, THETAS["true"][None, :], CompensateSettings())
    rel = np.abs(out.n_rl - b.inputs.n_rl) / np.maximum(np.abs(b.inputs.n_rl), 0.5)
    # R = 1000 smooths even true rates a little; the paper reports changes below 1.2 %
    assert np.mean(rel) < 0.012
    assert out.solved.all()


def test_result_does_not_depend_on_worker_count(batch: SegmentBatch) -> None:
    thetas = np.stack([THETAS["true"], THETAS["step-1-like"]])
    part = batch.take(slice(0, 12))
    one = compensate_batch(part, thetas, CompensateSettings(), workers=1)
    two = compensate_batch(part, thetas, CompensateSettings(), workers=2)
    np.testing.assert_array_equal(one.n_rl, two.n_rl)
    np.testing.assert_array_equal(one.n_rr, two.n_rr)
    np.testing.assert_array_equal(one.status, two.status)
    assert set(np.unique(one.status)) <= {SOLVED_FAST, SOLVED_KKT, SOLVED_OSQP}


def test_osqp_solver_setting(batch: SegmentBatch) -> None:
    settings = CompensateSettings(solver="osqp")
    p = problem(batch, 2, THETAS["true"])
    ref = solve_qp(p, settings)
    ours = solve_qp(p, CompensateSettings())
    assert ref.status == SOLVED_OSQP
    assert abs(ref.objective - ours.objective) <= 1e-6 * abs(ours.objective)


def test_relinearisation_lowers_the_nonlinear_cost(batch: SegmentBatch) -> None:
    theta = THETAS["step-1-like"]
    inputs, ref = segment(batch, 4)
    once = compensate_segment(theta, inputs, ref, batch.t_s, CompensateSettings(linearisations=1))
    thrice = compensate_segment(theta, inputs, ref, batch.t_s,
                                CompensateSettings(linearisations=3))
    assert once.solved and thrice.solved
    # the QP at the last linearisation point is exact there: its optimum cannot be worse than
    # the nominal (measured) rates evaluated by the same QP
    p_last = build_problem(theta, inputs, ref, batch.t_s, CompensateSettings(),
                           nominal_rates=thrice.rates)
    zero = np.zeros(5 * p_last.steps)
    # (three linearisations bring the nonlinear cost to well under a tenth of the first's)
    assert p_last.objective(zero) < 0.1 * problem(batch, 4, theta).objective(zero)


def _one_by_one(batch: SegmentBatch, thetas: np.ndarray,
                settings: CompensateSettings) -> tuple[np.ndarray, np.ndarray]:
    """Step 2 as the paper states it: each segment compensated with each theta in turn (warm
    started from its last active bounds), the solved rates averaged."""
    means, statuses = [], []
    for i in range(len(batch)):
        inputs, ref = segment(batch, i)
        active, solved, status = None, [], []
        for theta in thetas:
            seg = compensate_segment(theta, inputs, ref, batch.t_s, settings,
                                     initial_active=active)
            status.append(seg.status)
            if seg.solved:
                solved.append(seg.rates)
            if seg.active_rates is not None:
                active = seg.active_rates
        measured = np.column_stack([inputs.n_rl, inputs.n_rr])
        means.append(np.mean(solved, axis=0) if solved else measured)
        statuses.append(status)
    return np.array(means), np.array(statuses)


@pytest.mark.parametrize("settings", [
    CompensateSettings(),
    # state bounds that bind: the QPs need the banded-KKT path after the Riccati one; two
    # linearisations carry the active bounds from one to the next
    CompensateSettings(state_bounds=(0.15, 0.15, 0.008), linearisations=2),
    CompensateSettings(solver="osqp"),
], ids=["default", "state-bounds-relinearised", "osqp"])
def test_the_batched_step_2_solves_each_segment_as_alone(batch: SegmentBatch,
                                                         settings: CompensateSettings) -> None:
    """compensate_batch linearises a chunk's QPs together and solves them in one compiled
    call: the same rates and statuses as one segment at a time."""
    part = batch.take(slice(0, 6))
    thetas = np.stack([THETAS["step-1-like"], THETAS["datasheet"], THETAS["true"]])
    out = compensate_batch(part, thetas, settings)
    rates, status = _one_by_one(part, thetas, settings)
    np.testing.assert_array_equal(out.status, status)
    np.testing.assert_allclose(out.n_rl, rates[..., 0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out.n_rr, rates[..., 1], rtol=1e-12, atol=1e-12)
    if settings.solver == "structured" and settings.linearisations == 2:
        assert SOLVED_KKT in status
