"""The joint errors-in-variables calibration (``--method joint``): beyond the paper.

The three-step method cannot be unbiased: its compensated rates are computed with step-1
parameters and inherit them. Here the wheel rates are measurements like the poses, and one
maximum a posteriori problem over the whole drive has the poses, the true wheel rates and theta
as unknowns, with three kinds of residual, each weighted by its noise::

    model        (x_{b+1} - F(x_b, n~ + dn_b, theta)) / sigma_f    (what the model leaves out)
    reference    (x_b - y~_b) / sigma_y                              (the reference pose's noise)
    wheel rates  dn_b / sigma_n                                      (the encoders' noise)

The true rates are the measured ones plus a correction ``dn_b`` per block of ``block_s``
(5 s by default), and ``F`` is the exact 40 Hz model rolled out across the block from its
boundary pose ``x_b``. A correction per sample (``block_s`` = one sample) is the textbook
formulation, but the errors it would have to explain are not white at 40 Hz: encoder ticks
counted over a window, quantisation (whose errors telescope), slip correlated over a second,
small clock delays. Against the truth on simulated drives the per-sample form missed t_r by
10-20 cm with those profiles, while a block's mean error is close to white. Short blocks have a
second weakness: the noise estimation cannot fully tell reference-heading noise from wheel noise
(in errors-in-variables problems the variance ratio is only weakly identified), and the more
wheel noise a block leaves, the more t_r is pulled; the default block is the length at which
that stopped mattering on every simulated profile.

Ordering the unknowns block by block, ``[x_b (3), dn_b (2)]``, makes the Gauss-Newton normal
equations banded (half-width 7) with a dense border for theta. Each step factorises the banded
block by Cholesky (LAPACK ``dpbtrf``) and eliminates theta through its 4x4 Schur complement, in
time linear in the drive length. Pieces (gaps, file boundaries) have no model residual between
them: each has its own start pose. A block where the encoders read exactly zero and the
reference does not move is a stop: its correction is held to zero tightly.

Noise levels left unset are estimated by variance-component estimation: after each solve, a
group's variance becomes its weighted residual sum of squares over its redundancy (its share
of the degrees of freedom), ``n_g - tr(J_g H^-1 J_g^T)``, the trace found by Hutchinson's
estimator with seeded random probes. The covariance of theta is the inverse Schur complement.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

from odocal.drive import Drive
from odocal.errors import DataError, SolverError
from odocal.estimate import (
    CovarianceKind,
    Estimate,
    NotIdentified,
    Reason,
    Status,
    failed_estimate,
    few_clusters_inflation,
    held_as_weak,
    judge,
    weak,
)
from odocal.model import PARAMETER_NAMES, Inputs, Parameters, block_rollout, wrap_angle
from odocal.segments import common_sampling_time
from odocal.settings import Settings

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
log = logging.getLogger(__name__)

_BW = 7                  # half-bandwidth of the stage-ordered normal equations
_STAGE = 5               # unknowns per sample: x (3), n (2)
_AT_REST = 0.05          # wheel-noise factor for samples whose encoders read exactly zero
GROUPS = ("wheels", "reference_position", "reference_heading", "process_position",
          "process_heading")
#: Smallest noise levels the estimation may reach (a noise-free drive has none at all).
_FLOOR = {"wheels": 1e-6, "reference_position": 1e-5, "reference_heading": 1e-7,
          "process_position": 1e-6, "process_heading": 1e-8}
_FIELD = {"wheels": "wheels_revps", "reference_position": "reference_position_m",
          "reference_heading": "reference_heading_rad", "process_position": "process_position_m",
          "process_heading": "process_heading_rad"}


@dataclass(frozen=True)
class _Data:
    """Every block of every piece, one after another.

    Node b is the pose at a block boundary; block b (when ``link[b]``) runs from node b to b+1.
    """

    n_rl: FloatArray         # (B, L) measured rates of each block (zeros where not linked)
    n_rr: FloatArray
    beta: FloatArray         # (B, L)
    a_y: FloatArray          # (B, L)
    y: FloatArray            # (B+1, 3) reference poses at the nodes
    link: BoolArray          # (B,) node b and b+1 belong to the same piece
    at_rest: BoolArray       # (B+1,) the block starting at the node is a stop
    pose_std: FloatArray | None   # (B+1, 3) reference std where the log has it
    t_s: float
    pieces: int
    samples: int


def _gather(drives: Sequence[Drive], block: int) -> _Data:
    parts: dict[str, list[FloatArray]] = {k: [] for k in ("n_rl", "n_rr", "beta", "a_y", "y",
                                                          "link", "rest", "std")}
    pieces = samples = 0
    have_std = all(d.pose_std is not None for d in drives)
    zero = np.zeros((1, block))
    for d in drives:
        for a, b in d.pieces:
            count = (b - a - 1) // block
            if count < 1:
                continue
            pieces += 1
            samples += count * block + 1
            nodes = a + block * np.arange(count + 1)
            rows = nodes[:-1, None] + np.arange(block)[None, :]
            for key in ("n_rl", "n_rr", "beta", "a_y"):
                parts[key] += [getattr(d, key)[rows], zero]
            parts["y"].append(np.column_stack([d.x[nodes], d.y[nodes], d.psi[nodes]]))
            parts["link"].append(np.concatenate([np.ones(count, dtype=bool), [False]]))
            moved = np.hypot(np.diff(d.x[nodes]), np.diff(d.y[nodes]))
            still = (d.n_rl[rows] == 0).all(axis=1) & (d.n_rr[rows] == 0).all(axis=1) \
                & (moved < 0.05)
            parts["rest"].append(np.concatenate([still, [False]]))
            if have_std:
                assert d.pose_std is not None
                parts["std"].append(d.pose_std[nodes])
    if not pieces:
        raise DataError(f"joint calibration: no piece of the drives is longer than one block of "
                        f"{block} samples")
    cat: dict[str, NDArray[Any]] = {k: np.concatenate(v) for k, v in parts.items() if v}
    return _Data(n_rl=cat["n_rl"][:-1], n_rr=cat["n_rr"][:-1], beta=cat["beta"][:-1],
                 a_y=cat["a_y"][:-1], y=cat["y"], link=cat["link"][:-1].astype(bool),
                 at_rest=cat["rest"].astype(bool),
                 pose_std=cat.get("std") if have_std else None,
                 t_s=common_sampling_time(drives), pieces=pieces, samples=samples)


@dataclass(frozen=True)
class NoiseLevels:
    """Standard deviations per block of the three kinds of residual."""

    wheels_revps: float
    reference_position_m: float
    reference_heading_rad: float
    process_position_m: float
    process_heading_rad: float

    def to_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)


@dataclass
class _Weights:
    f: FloatArray            # (3,) model
    y: FloatArray            # (B+1, 3) reference
    n: FloatArray            # (B+1, 2) wheel corrections

    @classmethod
    def of(cls, data: _Data, noise: NoiseLevels) -> _Weights:
        f = 1.0 / np.array([noise.process_position_m, noise.process_position_m,
                            noise.process_heading_rad])
        sigma_y = np.array([noise.reference_position_m, noise.reference_position_m,
                            noise.reference_heading_rad])
        if data.pose_std is not None:
            # the fusion's own std shapes the weights; the level scales them
            shape = data.pose_std / np.maximum(np.median(data.pose_std, axis=0), 1e-12)
            y = 1.0 / (sigma_y * np.maximum(shape, 0.2))
        else:
            y = np.broadcast_to(1.0 / sigma_y, data.y.shape).copy()
        n = np.full((data.y.shape[0], 2), 1.0 / noise.wheels_revps)
        n[data.at_rest] /= _AT_REST
        return cls(f=f, y=y, n=n)


@dataclass(frozen=True)
class _System:
    """Residuals and normal equations at one point."""

    cost_parts: dict[str, float]
    chol: FloatArray          # banded Cholesky factor of H_zz
    h_zt: FloatArray          # (5N, p)
    h_tt: FloatArray          # (p, p)
    g_z: FloatArray           # (5N,)
    g_t: FloatArray           # (p,)

    @property
    def cost(self) -> float:
        return sum(self.cost_parts.values())


def _model_terms(z: FloatArray, theta: FloatArray, data: _Data
                 ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Model residual x_{b+1} - F(x_b, n~ + dn_b) of every block and its Jacobians (unweighted).

    Returns r (B, 3), J_z (B, 3, 8) over [x_b, dn_b, x_{b+1}], J_theta (B, 3, 4), and the
    block-end poses. F and its derivatives are the model's block rollout
    (:func:`odocal.model.block_rollout`).
    """
    x, dn = z[:, :3], z[:, 3:]
    end, jac = block_rollout(theta, Inputs(n_rl=data.n_rl, n_rr=data.n_rr, beta=data.beta,
                                           a_y=data.a_y), x[:-1], dn[:-1], data.t_s)
    r = x[1:] - end
    r[:, 2] = wrap_angle(r[:, 2])
    jz = np.zeros((end.shape[0], 3, 8))
    jz[:, :, :5] = -jac[:, :, :5]
    jz[:, 0, 5] = jz[:, 1, 6] = jz[:, 2, 7] = 1.0
    return r, jz, -jac[:, :, 5:], end


def _cost(z: FloatArray, theta: FloatArray, data: _Data, wt: _Weights) -> dict[str, float]:
    rf, _, _, _ = _model_terms(z, theta, data)
    rf = rf[data.link] * wt.f
    ry = z[:, :3] - data.y
    ry[:, 2] = wrap_angle(ry[:, 2])
    ry *= wt.y
    rn = z[:, 3:] * wt.n
    return {"model": float(np.sum(rf**2)), "reference": float(np.sum(ry**2)),
            "wheels": float(np.sum(rn**2))}


def _assemble(z: FloatArray, theta: FloatArray, free: BoolArray, data: _Data,
              wt: _Weights) -> _System:
    """Normal equations (banded block, border, gradient) at (z, theta), factorised."""
    n_samples = z.shape[0]
    size = _STAGE * n_samples
    r, jz, jt, _ = _model_terms(z, theta, data)
    mask = data.link.astype(np.float64)[:, None]
    r = r * wt.f * mask
    jz = jz * (wt.f[None, :, None] * mask[:, :, None])
    jt = jt[:, :, free] * (wt.f[None, :, None] * mask[:, :, None])
    blocks = np.einsum("kia,kib->kab", jz, jz)                 # (N-1, 8, 8)
    grad_blocks = -np.einsum("kia,ki->ka", jz, r)              # (N-1, 8)
    border_blocks = np.einsum("kia,kip->kap", jz, jt)          # (N-1, 8, p)
    ab = np.zeros((_BW + 1, size))
    g_z = np.zeros(size)
    h_zt = np.zeros((size, int(free.sum())))
    for parity in (0, 1):                  # blocks k and k+2 never overlap: add in two passes
        ks = np.arange(parity, n_samples - 1, 2)
        base = _STAGE * ks
        for a in range(8):
            g_z[base + a] += grad_blocks[ks, a]
            h_zt[base + a] += border_blocks[ks, a]
            for b in range(a, 8):
                ab[_BW + a - b, base + b] += blocks[ks, a, b]
    ry = z[:, :3] - data.y
    ry[:, 2] = wrap_angle(ry[:, 2])
    rn = z[:, 3:]
    idx = _STAGE * np.arange(n_samples)
    for i in range(3):
        ab[_BW, idx + i] += wt.y[:, i] ** 2
        g_z[idx + i] -= wt.y[:, i] ** 2 * ry[:, i]
    for i in range(2):
        ab[_BW, idx + 3 + i] += wt.n[:, i] ** 2
        g_z[idx + 3 + i] -= wt.n[:, i] ** 2 * rn[:, i]
    chol, info = lapack.dpbtrf(ab, lower=0, overwrite_ab=1)
    if info != 0:
        raise SolverError(f"joint calibration: the normal equations are not positive definite "
                          f"(LAPACK info {info})")
    h_tt = np.einsum("kip,kiq->pq", jt, jt)
    g_t = -np.einsum("kip,ki->p", jt, r)
    parts = _cost(z, theta, data, wt)
    return _System(cost_parts=parts, chol=chol, h_zt=h_zt, h_tt=h_tt, g_z=g_z, g_t=g_t)


def _solve_z(system: _System, rhs: FloatArray) -> FloatArray:
    out, info = lapack.dpbtrs(system.chol, rhs, lower=0)
    if info != 0:  # pragma: no cover - dpbtrf succeeded, so this cannot fail
        raise SolverError(f"joint calibration: banded solve failed (LAPACK info {info})")
    return np.asarray(out)


def _solve(system: _System, u_z: FloatArray, u_t: FloatArray
           ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """H [a; b] = [u_z; u_t] by the Schur complement; also returns S. u may have columns."""
    x_zt = _solve_z(system, system.h_zt) if system.h_zt.shape[1] else system.h_zt
    y = _solve_z(system, u_z)
    schur = system.h_tt - system.h_zt.T @ x_zt
    if schur.size:
        b = np.linalg.solve(schur, u_t - system.h_zt.T @ y)
        a = y - x_zt @ b
    else:
        b, a = u_t, y
    return a, np.asarray(b, dtype=np.float64), schur


@dataclass(frozen=True)
class _Solution:
    z: FloatArray
    theta: FloatArray
    free: BoolArray
    system: _System
    history: list[float]
    iterations: int
    converged: bool


def _gauss_newton(z: FloatArray, theta: FloatArray, free: BoolArray, data: _Data,
                  wt: _Weights, max_iterations: int) -> _Solution:
    system = _assemble(z, theta, free, data, wt)
    history = [system.cost]
    converged = False
    iterations = 0
    for _ in range(max_iterations):
        dz, dt, _ = _solve(system, system.g_z, system.g_t)
        step = 1.0
        accepted = False
        for _halving in range(12):
            z_new = z + step * dz.reshape(z.shape)
            th_new = theta.copy()
            th_new[free] += step * dt
            if th_new[0] > 0 and th_new[2] > 0:
                new_cost = sum(_cost(z_new, th_new, data, wt).values())
                if np.isfinite(new_cost) and new_cost < history[-1]:
                    accepted = True
                    break
            step *= 0.5
        if not accepted:
            converged = True                  # no descent left: at the minimum
            break
        z, theta = z_new, th_new
        system = _assemble(z, theta, free, data, wt)
        history.append(system.cost)
        iterations += 1
        if history[-2] - history[-1] <= 1e-10 * history[-1]:
            converged = True
            break
    return _Solution(z=z, theta=theta, free=free, system=system, history=history,
                     iterations=iterations, converged=converged)


def _redundancy(solution: _Solution, wt: _Weights, data: _Data, groups: Sequence[str],
                probes: int, rng: np.random.Generator) -> dict[str, float]:
    """Each noise group's share of the degrees of freedom, ``n_g - tr(J_g H^-1 J_g^T)``.

    The trace is Hutchinson's estimate ``E[v^T J_g H^-1 J_g^T v]`` over random sign vectors v.
    """
    system = solution.system
    n_samples = solution.z.shape[0]
    size = _STAGE * n_samples
    free_p = system.h_tt.shape[0]
    idx = _STAGE * np.arange(n_samples)
    _, jz, jt, _ = _model_terms(solution.z, solution.theta, data)
    links = np.flatnonzero(data.link)
    jz = jz[links] * wt.f[None, :, None]
    jt = jt[links][:, :, : jt.shape[2]] * wt.f[None, :, None]
    out = {}
    for group in groups:
        if group.startswith("process"):
            rows = [0, 1] if group == "process_position" else [2]
            v = rng.choice([-1.0, 1.0], size=(links.size, len(rows), probes))
            u = np.zeros((size, probes))
            ut = np.zeros((4, probes))
            for j, row in enumerate(rows):
                contrib = jz[:, row, :, None] * v[:, j, None, :]      # (L, 8, P)
                for a in range(8):
                    np.add.at(u, _STAGE * links + a, contrib[:, a])
                ut += np.einsum("lp,lq->pq", jt[:, row], v[:, j])
            a_z, a_t, _ = _solve(system, u, ut[solution.free])
            quad = np.zeros(probes)
            for j, row in enumerate(rows):
                back = np.zeros((links.size, probes))
                for a in range(8):
                    back += jz[:, row, a, None] * a_z[_STAGE * links + a]
                back += np.einsum("lp,pq->lq", jt[:, row][:, solution.free],
                                  a_t)
                quad += np.einsum("lq,lq->q", v[:, j], back)
            out[group] = float(links.size * len(rows) - quad.mean())
            continue
        cols, w = {"reference_position": ([0, 1], wt.y[:, :2]),
                   "reference_heading": ([2], wt.y[:, 2:3]),
                   "wheels": ([3, 4], wt.n)}[group]
        v = rng.choice([-1.0, 1.0], size=(n_samples, len(cols), probes))
        u = np.zeros((size, probes))
        for j, c in enumerate(cols):
            u[idx + c] = w[:, j, None] * v[:, j]
        a_z, _, _ = _solve(system, u, np.zeros((free_p, probes)))
        quad = np.zeros(probes)
        for j, c in enumerate(cols):
            quad += np.einsum("kp,kp->p", w[:, j, None] * v[:, j], a_z[idx + c])
        out[group] = float(w.size - quad.mean())
    return out


def _initial_noise(settings: Settings) -> NoiseLevels:
    """Starting levels: the settings' where given, else round numbers the estimation refines."""
    js = settings.joint
    return NoiseLevels(
        wheels_revps=js.wheel_noise_revps or 0.01,
        reference_position_m=js.reference_position_m or 0.05,
        reference_heading_rad=js.reference_heading_rad or 0.003,
        process_position_m=js.process_position_m or 0.01,
        process_heading_rad=js.process_heading_rad or 1e-3)


@dataclass(frozen=True)
class JointDetails:
    """What the joint calibration did (see the module docstring).

    noise : the noise levels of the final solve; ``estimated`` names those found from the data
    noise_history : the levels and the cost of every solve
    cost_parts : the final cost split into its model, reference and wheel parts
    iterations : Gauss-Newton iterations over all solves
    sensitivity : theta's change (in standard deviations) with the wheel noise halved, doubled
    residual_rms : RMS of the reference residuals p_x, p_y (m) and psi (rad)
    warnings : what the user should know
    """

    noise: NoiseLevels
    estimated: tuple[str, ...]
    noise_history: list[dict[str, float]]
    cost_parts: dict[str, float]
    iterations: int
    sensitivity: dict[str, dict[str, float]]
    pieces: int
    samples: int
    residual_rms: tuple[float, float, float]
    elapsed_s: float
    warnings: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        return {"noise": self.noise.to_dict(), "noise_estimated": list(self.estimated),
                "noise_history": self.noise_history, "cost_parts": self.cost_parts,
                "iterations": self.iterations, "wheel_noise_sensitivity_std": self.sensitivity,
                "pieces": self.pieces, "samples": self.samples,
                "residual_rms": {"p_x_m": self.residual_rms[0], "p_y_m": self.residual_rms[1],
                                 "psi_rad": self.residual_rms[2]},
                "elapsed_s": self.elapsed_s}


@dataclass
class _Run:
    """The state the joint calibration carries from solve to solve."""

    data: _Data
    settings: Settings
    noise: NoiseLevels
    z: FloatArray
    theta: FloatArray
    free: BoolArray
    history: list[dict[str, float]] = field(default_factory=list)
    iterations: int = 0

    def solve(self, noise: NoiseLevels | None = None) -> tuple[_Solution, _Weights]:
        """Gauss-Newton at ``noise`` (default: the current levels), warm-started."""
        wt = _Weights.of(self.data, noise or self.noise)
        sol = _gauss_newton(self.z, self.theta, self.free, self.data, wt,
                            self.settings.joint.max_iterations)
        self.history.append({**(noise or self.noise).to_dict(), "cost": sol.system.cost})
        self.iterations += sol.iterations
        return sol, wt

    def accept(self, sol: _Solution) -> None:
        self.z, self.theta = sol.z, sol.theta


def joint_calibration(drives: Sequence[Drive], *, settings: Settings,
                      held: Mapping[str, NotIdentified] | None = None,
                      progress: Callable[[str, int, int], None] | None = None) -> Estimate:
    """Calibrate theta jointly with the poses and the true wheel rates of every sample.

    Returns an :class:`~odocal.estimate.Estimate` with :class:`JointDetails`; a factorisation
    that breaks down gives a failed estimate (``Status.SOLVER_FAILED``), not an exception.
    """
    started = time.perf_counter()
    js = settings.joint
    t_s = common_sampling_time(drives)
    data = _gather(drives, max(round(js.block_s / t_s), 1))  # (pieces of one block at least)
    datasheet = np.asarray(settings.identify.theta0, dtype=np.float64)
    held = dict(held or {})
    run = _Run(data=data, settings=settings, noise=_initial_noise(settings),
               z=np.concatenate([data.y, np.zeros((data.y.shape[0], 2))], axis=1),
               theta=datasheet.copy(),
               free=np.array([name not in held for name in PARAMETER_NAMES]))
    warnings: list[str] = []
    # independent evidence: pieces of drive a segment long (as the other methods' clusters)
    chunk = settings.segments.length
    block = max(round(js.block_s / t_s), 1)
    n_clusters = sum(max((b - a) // chunk, 1) for d in drives for a, b in d.pieces
                     if b - a - 1 >= block)
    if n_clusters < 2 and settings.identify.judge_identifiability:
        for name in PARAMETER_NAMES:
            held.setdefault(name, NotIdentified(Reason.ONE_CLUSTER, detail=float(n_clusters)))
        run.free = np.array([name not in held for name in PARAMETER_NAMES])
    try:
        estimated = _estimate_noise(run, warnings, progress)
        sol, _ = run.solve()
        run.accept(sol)
        cov = _theta_covariance(sol, run.free)
        too_weak = weak(np.sqrt(np.clip(np.diag(cov), 0.0, None)), run.free, settings.identify)
        if too_weak.any():
            held.update(held_as_weak(np.sqrt(np.diag(cov)), too_weak, settings.identify))
            run.free = run.free & ~too_weak
            run.theta[~run.free] = datasheet[~run.free]
            sol, _ = run.solve()
            run.accept(sol)
            cov = _theta_covariance(sol, run.free)
        cov = cov * few_clusters_inflation(max(n_clusters, 2)) ** 2
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        sensitivity = _sensitivity(run, sol, std, warnings)
    except SolverError:
        log.warning("joint calibration: the normal equations could not be factorised")
        return failed_estimate("joint", settings.identify, Status.SOLVER_FAILED)
    residual_y = sol.z[:, :3] - data.y
    residual_y[:, 2] = wrap_angle(residual_y[:, 2])
    rms = np.sqrt(np.mean(residual_y**2, axis=0))
    details = JointDetails(noise=run.noise, estimated=estimated, noise_history=run.history,
                           cost_parts=sol.system.cost_parts, iterations=run.iterations,
                           sensitivity=sensitivity, pieces=data.pieces, samples=data.samples,
                           residual_rms=(float(rms[0]), float(rms[1]), float(rms[2])),
                           elapsed_s=time.perf_counter() - started, warnings=tuple(warnings))
    if not run.free.any():
        status = Status.NOTHING_IDENTIFIABLE
    elif sol.system.cost < 1e-12 * data.samples:
        status = Status.EXACT
    else:
        status = Status.SETTLED if sol.converged else Status.ITERATION_LIMIT
    return Estimate(method="joint", theta=Parameters.from_array(run.theta),
                    datasheet=Parameters.from_array(datasheet), covariance=cov,
                    covariance_kind=CovarianceKind.JOINT,
                    free=tuple(bool(f) for f in run.free),  # type: ignore[arg-type]
                    verdicts=judge(std, run.free, settings.identify, held=held), status=status,
                    details=details)


def _estimate_noise(run: _Run, warnings: list[str],
                    progress: Callable[[str, int, int], None] | None) -> tuple[str, ...]:
    """Variance-component estimation of the noise levels left unset; returns their names."""
    js = run.settings.joint
    given = {"wheels": js.wheel_noise_revps, "reference_position": js.reference_position_m,
             "reference_heading": js.reference_heading_rad,
             "process_position": js.process_position_m,
             "process_heading": js.process_heading_rad}
    estimate = tuple(g for g in GROUPS if given[g] is None)
    rng = np.random.default_rng(run.settings.calibrate.seed)
    rounds = js.noise_rounds if estimate else 0
    settled = not estimate
    previous: FloatArray | None = None
    for round_ in range(rounds):
        if progress:
            progress("joint: noise estimation", round_, rounds)
        sol, wt = run.solve()
        run.accept(sol)
        red = _redundancy(sol, wt, run.data, estimate, js.trace_probes, rng)
        parts = _group_ss(sol, run.data, wt)
        scale = {g: parts[g] / max(red[g], 1.0) for g in estimate}
        run.noise = dataclasses.replace(run.noise, **{
            _FIELD[g]: max(getattr(run.noise, _FIELD[g]) * float(np.sqrt(scale[g])), _FLOOR[g])
            for g in estimate})
        # Settled when theta stops moving (against its own standard deviation) and so does the
        # wheel level, which is what the errors-in-variables correction rests on. A reference
        # error correlated over seconds is hard to tell from process noise at block level, so
        # those two levels may keep trading slowly without changing theta.
        std = _theta_std(sol, run.free)
        free = run.free
        moved = np.inf if previous is None else float(
            np.max(np.abs(run.theta - previous)[free] / np.maximum(std[free], 1e-300),
                   initial=0.0))
        previous = run.theta.copy()
        wheel_change = abs(np.sqrt(scale.get("wheels", 1.0)) - 1.0)
        if (moved < 0.05 and wheel_change < 0.05) or sol.system.cost < 1e-12 * run.data.samples:
            settled = True                   # (a noise-free drive: nothing left to estimate)
            break
    if not settled:
        warnings.append(f"theta or the wheel-noise level was still moving after {rounds} "
                        "rounds of variance-component estimation")
    if progress:
        progress("joint: noise estimation", rounds, rounds)
    return estimate


def _sensitivity(run: _Run, sol: _Solution, std: FloatArray,
                 warnings: list[str]) -> dict[str, dict[str, float]]:
    """theta's move, in standard deviations, with the wheel-noise level halved and doubled."""
    js = run.settings.joint
    out: dict[str, dict[str, float]] = {}
    if not js.sensitivity or not run.free.any():
        return out
    for label, factor in (("halved", 0.5), ("doubled", 2.0)):
        alt = _Weights.of(run.data, dataclasses.replace(
            run.noise, wheels_revps=run.noise.wheels_revps * factor))
        other = _gauss_newton(sol.z, run.theta, run.free, run.data, alt, js.max_iterations)
        out[label] = {n: float((other.theta[j] - run.theta[j]) / std[j])
                      if run.free[j] and std[j] > 0 else 0.0
                      for j, n in enumerate(PARAMETER_NAMES)}
    worst = max(abs(v) for d in out.values() for v in d.values())
    if worst > 1.0:
        warnings.append(f"theta moves by up to {worst:.1f} standard deviations when the "
                        "wheel-noise level is halved or doubled: the estimate depends on "
                        "that level")
    return out


def _theta_covariance(sol: _Solution, free: BoolArray) -> FloatArray:
    """theta's covariance: the inverse Schur complement, embedded in 4x4."""
    cov = np.zeros((4, 4))
    if free.any():
        _, _, schur = _solve(sol.system, np.zeros(sol.system.g_z.shape[0]),
                             np.zeros(int(free.sum())))
        cov[np.ix_(free, free)] = np.linalg.inv(schur)
    return cov


def _theta_std(sol: _Solution, free: BoolArray) -> FloatArray:
    return np.sqrt(np.clip(np.diag(_theta_covariance(sol, free)), 0.0, None))


def _group_ss(sol: _Solution, data: _Data, wt: _Weights) -> dict[str, float]:
    """Weighted residual sums of squares of the noise groups."""
    ry = sol.z[:, :3] - data.y
    ry[:, 2] = wrap_angle(ry[:, 2])
    ry *= wt.y
    rn = sol.z[:, 3:] * wt.n
    rf, _, _, _ = _model_terms(sol.z, sol.theta, data)
    rf = rf[data.link] * wt.f
    return {"reference_position": float(np.sum(ry[:, :2] ** 2)),
            "reference_heading": float(np.sum(ry[:, 2] ** 2)), "wheels": float(np.sum(rn**2)),
            "process_position": float(np.sum(rf[:, :2] ** 2)),
            "process_heading": float(np.sum(rf[:, 2] ** 2))}
