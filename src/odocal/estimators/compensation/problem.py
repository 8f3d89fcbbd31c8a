"""METHOD 4: the input-compensation QP of one segment, in deviation variables.

Around a nominal trajectory ``x^`` rolled out with nominal wheel rates ``n^`` (the measured ones at
the first linearisation), the model is linearised (10a)-(10b) and the QP (11) becomes, in
deviations ``dn_k = n_k - n^_k`` and ``dx_k = x_k - x^_k``::

    min  sum_{k=1..K} ||e_k - dx_k||_Q^2
         + sum_{k=1..K-1} ||(n^_k + dn_k) - (n^_{k-1} + dn_{k-1})||_R^2
    s.t. dx_0 = 0,  dx_k = A_k dx_{k-1} + B_k dn_{k-1}                       (linearised model)
         -b - x^_k + y~_k <= dx_k <= b - x^_k + y~_k                           (state bounds)
         (1 - r) n~_k - n^_k <= dn_k <= (1 + r) n~_k - n^_k                   (rate bounds)

with ``e_k = y~_k - x^_k``. Stacking ``z = [dn_0, dx_1, dn_1, dx_2, ..., dn_{K-1}, dx_K]`` (five
numbers per stage) gives ``min 1/2 z^T P z + q^T z + c  s.t.  E z = 0,  l <= z <= u`` whose matrices
are banded in time. Both solvers (the structured one and the OSQP reference) solve exactly this.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray
from odocal.model.jacobians import linearised_rollout
from odocal.model.parameters import Inputs
from odocal.settings import CompensateSettings

STAGE = 5  # variables per stage: dn (2) then dx (3)


@dataclass(frozen=True)
class CompensationProblem:
    """One linearised QP (see the module docstring).

    nominal_rates : ndarray, shape (K, 2)
        n^, the linearisation point (rev/s).
    nominal_poses : ndarray, shape (K+1, 3)
        x^, the nominal trajectory.
    A, B : ndarray, shapes (K, 3, 3) and (K, 3, 2)
        Step Jacobians; step k maps pose k to pose k+1 with rates k.
    tracking_error : ndarray, shape (K, 3)
        e_k = y~_k - x^_k for k = 1..K.
    rate_change : ndarray, shape (K-1, 2)
        n^_k - n^_{k-1} for k = 1..K-1.
    q_diag, r_diag : diagonals of Q and R
    lower, upper : ndarray, shape (K, 5)
        Bounds of [dn_{k-1}, dx_k] per stage k = 1..K.
    """

    nominal_rates: FloatArray
    nominal_poses: FloatArray
    A: FloatArray
    B: FloatArray
    tracking_error: FloatArray
    rate_change: FloatArray
    q_diag: FloatArray
    r_diag: FloatArray
    lower: FloatArray
    upper: FloatArray

    @property
    def steps(self) -> int:
        return int(self.A.shape[0])

    def objective(self, z: FloatArray) -> float:
        """The QP's objective (11) at ``z``, constant included (so it is the paper's cost)."""
        stages = z.reshape(self.steps, STAGE)
        dn, dx = stages[:, :2], stages[:, 2:]
        track = self.tracking_error - dx
        change = self.rate_change + np.diff(dn, axis=0)
        return float(np.einsum("ki,i,ki->", track, self.q_diag, track)
                     + np.einsum("ki,i,ki->", change, self.r_diag, change))

    def gradient_terms(self) -> tuple[FloatArray, float]:
        """Diagonal blocks' data: q of ``1/2 z^T P z + q^T z`` as an array (K, 5), and the
        constant, so that ``objective(z) = 1/2 z^T P z + q^T z + constant``."""
        q = np.zeros((self.steps, STAGE))
        q[:, 2:] = -2.0 * self.tracking_error * self.q_diag
        rc = 2.0 * self.rate_change * self.r_diag                 # (K-1, 2)
        q[1:, :2] += rc
        q[:-1, :2] -= rc
        constant = float(np.einsum("ki,i,ki->", self.tracking_error, self.q_diag,
                                   self.tracking_error)
                         + np.einsum("ki,i,ki->", self.rate_change, self.r_diag,
                                     self.rate_change))
        return q, constant

    def rates(self, z: FloatArray) -> FloatArray:
        """Absolute wheel rates n = n^ + dn, shape (K, 2)."""
        return self.nominal_rates + z.reshape(self.steps, STAGE)[:, :2]


def build_problem(theta: FloatArray, inputs: Inputs, reference: FloatArray, t_s: float,
                  settings: CompensateSettings, *,
                  nominal_rates: FloatArray | None = None) -> CompensationProblem:
    """Linearise one segment around ``nominal_rates`` (default: the measured ones).

    Parameters
    ----------
    theta : ndarray, shape (n,)
    inputs : Inputs with arrays of shape (K,); ``n_rl, n_rr`` are the measured rates n~
    reference : ndarray, shape (K+1, 3), the measured poses y~
    """
    measured = np.column_stack([inputs.n_rl, inputs.n_rr])
    nominal = measured if nominal_rates is None else nominal_rates
    u_nom = inputs.with_wheel_rates(nominal[:, 0], nominal[:, 1])
    poses, jac = linearised_rollout(theta, u_nom, reference[0], t_s)
    k = measured.shape[0]
    state_bound = np.asarray(settings.state_bounds)
    lo_rate = np.minimum((1 - settings.rate_bound) * measured, (1 + settings.rate_bound) * measured)
    hi_rate = np.maximum((1 - settings.rate_bound) * measured, (1 + settings.rate_bound) * measured)
    lower = np.empty((k, STAGE))
    upper = np.empty((k, STAGE))
    lower[:, :2] = lo_rate - nominal
    upper[:, :2] = hi_rate - nominal
    error = reference[1:] - poses[1:]
    lower[:, 2:] = error - state_bound
    upper[:, 2:] = error + state_bound
    return CompensationProblem(
        nominal_rates=nominal, nominal_poses=poses, A=jac.A, B=jac.B, tracking_error=error,
        rate_change=np.diff(nominal, axis=0), q_diag=np.asarray(settings.state_weights, float),
        r_diag=np.asarray(settings.rate_change_weights, float), lower=lower, upper=upper)


@dataclass(frozen=True)
class ProblemBatch:
    """The QPs of many segments of equal length, linearised at once (arrays with a leading
    segment axis, the fields of :class:`CompensationProblem`): one vectorised rollout and one
    set of step Jacobians for a chunk of segments instead of one per QP."""

    nominal_rates: FloatArray          # (N, K, 2)
    nominal_poses: FloatArray          # (N, K+1, 3)
    A: FloatArray                      # (N, K, 3, 3)
    B: FloatArray                      # (N, K, 3, 2)
    tracking_error: FloatArray         # (N, K, 3)
    rate_change: FloatArray            # (N, K-1, 2)
    q_diag: FloatArray
    r_diag: FloatArray
    lower: FloatArray                  # (N, K, 5)
    upper: FloatArray                  # (N, K, 5)

    def __len__(self) -> int:
        return int(self.A.shape[0])

    def problem(self, i: int) -> CompensationProblem:
        """Segment ``i``'s QP on its own."""
        return CompensationProblem(
            nominal_rates=self.nominal_rates[i], nominal_poses=self.nominal_poses[i],
            A=self.A[i], B=self.B[i], tracking_error=self.tracking_error[i],
            rate_change=self.rate_change[i], q_diag=self.q_diag, r_diag=self.r_diag,
            lower=self.lower[i], upper=self.upper[i])


def build_problems(theta: FloatArray, inputs: Inputs, reference: FloatArray, t_s: float,
                   settings: CompensateSettings, *,
                   nominal_rates: FloatArray | None = None) -> ProblemBatch:
    """:func:`build_problem` for many segments at once (inputs arrays (N, K), reference
    (N, K+1, 3), nominal_rates (N, K, 2)); ``problem(i)`` equals ``build_problem`` of segment
    ``i``."""
    measured = np.stack([inputs.n_rl, inputs.n_rr], axis=-1)
    nominal = measured if nominal_rates is None else nominal_rates
    u_nom = inputs.with_wheel_rates(nominal[..., 0], nominal[..., 1])
    poses, jac = linearised_rollout(theta, u_nom, reference[:, 0], t_s)
    n, k = inputs.n_rl.shape
    state_bound = np.asarray(settings.state_bounds)
    b = settings.rate_bound
    lower = np.empty((n, k, STAGE))
    upper = np.empty((n, k, STAGE))
    np.subtract(np.minimum((1 - b) * measured, (1 + b) * measured), nominal,
                out=lower[..., :2])
    np.subtract(np.maximum((1 - b) * measured, (1 + b) * measured), nominal,
                out=upper[..., :2])
    error = reference[:, 1:] - poses[:, 1:]
    np.subtract(error, state_bound, out=lower[..., 2:])
    np.add(error, state_bound, out=upper[..., 2:])
    return ProblemBatch(
        nominal_rates=nominal, nominal_poses=poses, A=jac.A, B=jac.B, tracking_error=error,
        rate_change=np.diff(nominal, axis=1), q_diag=np.asarray(settings.state_weights, float),
        r_diag=np.asarray(settings.rate_change_weights, float), lower=lower, upper=upper)
