"""Reference-pose fusion: an extended Kalman filter with a Rauch-Tung-Striebel smoothing pass.

State ``s = [x, y, psi, v, b, beta]``: position (m, ENU), heading (rad, counter-clockwise from
east), speed (m/s), the gyro's yaw-rate bias (rad/s) and the sideslip (rad). On the common grid
(step dt) the IMU yaw rate ``w`` drives the model::

    x+ = x + v dt cos(psi + beta)     y+ = y + v dt sin(psi + beta)     psi+ = psi + (w - b) dt
    v+ = v (random walk)              b+ = b (random walk)              beta+ = phi beta (Markov)

The vehicle moves along its course ``psi + beta``, not its heading: in a tight, slow turn the
two differ by several degrees, and a filter that ignored it would pull the heading toward the
course. The sideslip's spread follows how hard the vehicle turns (about ``l_r |w| / v``, small on
straights), so on straights the course pins the heading and in bends the gyro carries it.

GNSS position, speed and course over ground (the course measures ``psi + beta``, above a minimum
speed), and a heading (compass, dual antenna) where there is one, update the state. A measurement
whose normalised innovation exceeds the chi-square limit is rejected as an outlier and counted.
The backward RTS pass uses every measurement for every sample. The result is x, y, psi and beta
on the grid with the standard deviations of x, y, psi.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.errors import DataError
from odocal.model._jit import jit
from odocal.settings import FusionSettings


@jit
def _wrap(a: float) -> float:  # pragma: no cover - compiled
    return (a + np.pi) % (2.0 * np.pi) - np.pi


_N = 6                     # state size
_L_R = 1.5                 # rear axle to reference point, m, for the sideslip's expected spread
_BETA_TAU_S = 1.0          # sideslip correlation time


@jit
def _update(x: FloatArray, P: FloatArray, H: FloatArray, z: FloatArray, R: FloatArray,
            chi2: float, angle: bool) -> bool:  # pragma: no cover - compiled
    """Kalman update in place (Joseph form); False (and no change) for an outlier."""
    y = z - H @ x
    if angle:
        for i in range(y.shape[0]):
            y[i] = _wrap(y[i])
    S = H @ P @ H.T + np.diag(R)
    S_inv = np.linalg.inv(S)
    if y @ S_inv @ y > chi2 * y.shape[0]:
        return False
    K = P @ H.T @ S_inv
    x += K @ y
    A = np.eye(_N) - K @ H
    P[:, :] = A @ P @ A.T + K @ np.diag(R) @ K.T
    return True


@jit
def _ekf_rts(omega: FloatArray, dt: float, pos: FloatArray, pos_std: FloatArray,
             speed: FloatArray, course: FloatArray, heading: FloatArray, x0: FloatArray,
             P0: FloatArray, q: FloatArray, r_speed: float, r_course: float, r_heading: float,
             min_course_speed: float,
             chi2: float) -> tuple[FloatArray, FloatArray, IntArray,
                                   FloatArray]:  # pragma: no cover - compiled
    n = omega.shape[0]
    xp = np.zeros((n, _N))
    Pp = np.zeros((n, _N, _N))
    xf = np.zeros((n, _N))
    Pf = np.zeros((n, _N, _N))
    Fs = np.zeros((n, _N, _N))
    rejected = np.zeros(4, dtype=np.int64)     # per kind of measurement (not theta)
    innov_ss = np.zeros(2)                      # position innovations: sum of squares, count
    x = x0.copy()
    P = P0.copy()
    phi = np.exp(-dt / _BETA_TAU_S)
    H_pos = np.zeros((2, _N))
    H_pos[0, 0] = 1.0
    H_pos[1, 1] = 1.0
    H_v = np.zeros((1, _N))
    H_v[0, 3] = 1.0
    H_course = np.zeros((1, _N))
    H_course[0, 2] = 1.0
    H_course[0, 5] = 1.0
    H_psi = np.zeros((1, _N))
    H_psi[0, 2] = 1.0
    for k in range(n):
        if k > 0:
            c, s = np.cos(x[2] + x[5]), np.sin(x[2] + x[5])
            F = np.eye(_N)
            F[0, 2] = F[0, 5] = -x[3] * dt * s
            F[1, 2] = F[1, 5] = x[3] * dt * c
            F[0, 3] = dt * c
            F[1, 3] = dt * s
            F[2, 4] = -dt
            F[5, 5] = phi
            Fs[k - 1] = F
            turn = abs(omega[k - 1] - x[4])
            beta_std = min(max(_L_R * turn / max(abs(x[3]), 2.0), 0.002), 0.2)
            Q = np.diag(np.array([q[0] * dt, q[1] * dt, q[2] * dt, q[3] * dt, q[4] * dt,
                                  beta_std**2 * (1.0 - phi**2)]))
            x = np.array([x[0] + x[3] * dt * c, x[1] + x[3] * dt * s,
                          x[2] + (omega[k - 1] - x[4]) * dt, x[3], x[4], phi * x[5]])
            P = F @ P @ F.T + Q
        xp[k] = x
        Pp[k] = P
        if np.isfinite(pos[k, 0]):
            y0, y1 = pos[k, 0] - x[0], pos[k, 1] - x[1]
            if _update(x, P, H_pos, pos[k].copy(), np.array([pos_std[k] ** 2, pos_std[k] ** 2]),
                       chi2, False):
                innov_ss[0] += y0 * y0 + y1 * y1
                innov_ss[1] += 2.0
            else:
                rejected[0] += 1
        if np.isfinite(speed[k]):
            if not _update(x, P, H_v, np.array([speed[k]]), np.array([r_speed ** 2]), chi2,
                           False):
                rejected[1] += 1
        if np.isfinite(course[k]) and np.isfinite(speed[k]) and speed[k] > min_course_speed:
            if not _update(x, P, H_course, np.array([course[k]]), np.array([r_course ** 2]),
                           chi2, True):
                rejected[2] += 1
        if np.isfinite(heading[k]):
            if not _update(x, P, H_psi, np.array([heading[k]]), np.array([r_heading ** 2]),
                           chi2, True):
                rejected[3] += 1
        xf[k] = x
        Pf[k] = P
    # Rauch-Tung-Striebel backward pass
    xs = xf.copy()
    Ps = Pf.copy()
    for k in range(n - 2, -1, -1):
        C = Pf[k] @ Fs[k].T @ np.linalg.inv(Pp[k + 1])
        d = xs[k + 1] - xp[k + 1]
        xs[k] = xf[k] + C @ d
        Ps[k] = Pf[k] + C @ (Ps[k + 1] - Pp[k + 1]) @ C.T
    std = np.zeros((n, _N))
    for k in range(n):
        for i in range(_N):
            std[k, i] = np.sqrt(max(Ps[k, i, i], 0.0))
    return xs, std, rejected, innov_ss


@dataclass(frozen=True)
class FusedReference:
    """The fused reference on the grid.

    x, y, psi : ndarray, shape (N,), m, m, rad (unwrapped)
    std : ndarray, shape (N, 3), their standard deviations
    speed : ndarray, shape (N,), m/s
    gyro_bias : ndarray, shape (N,), rad/s
    sideslip : ndarray, shape (N,), rad (the course is psi + sideslip)
    rejected : outliers rejected per measurement kind
    position_innovation_rms_m : RMS of the accepted GNSS position innovations (filter pass)
    mirrored : with positions only, the filter had settled on the mirror image (speed negative,
        heading turned by pi) and the result was turned back
    """

    x: FloatArray
    y: FloatArray
    psi: FloatArray
    std: FloatArray
    speed: FloatArray
    gyro_bias: FloatArray
    sideslip: FloatArray
    rejected: dict[str, int]
    position_innovation_rms_m: float
    mirrored: bool = False

    def summary(self) -> dict[str, Any]:
        return {"rejected_outliers": dict(self.rejected), "mirrored": self.mirrored,
                "position_innovation_rms_m": self.position_innovation_rms_m,
                "gyro_bias_radps": float(np.median(self.gyro_bias)),
                "median_std": {"x_m": float(np.median(self.std[:, 0])),
                               "y_m": float(np.median(self.std[:, 1])),
                               "psi_rad": float(np.median(self.std[:, 2]))}}


def on_grid(t_grid: FloatArray, t_meas: FloatArray, values: FloatArray) -> IntArray:
    """Index of the grid point nearest to each measurement (-1 outside the grid)."""
    step = t_grid[1] - t_grid[0]
    idx = np.rint((t_meas - t_grid[0]) / step).astype(np.int64)
    idx[(idx < 0) | (idx >= t_grid.size)] = -1
    return idx


def fuse(t_grid: FloatArray, yaw_rate: FloatArray, *, gnss_t: FloatArray,
         east: FloatArray, north: FloatArray, gnss_speed: FloatArray | None,
         gnss_course: FloatArray | None, gnss_std: FloatArray | None,
         heading_t: FloatArray | None, heading: FloatArray | None,
         settings: FusionSettings, name: str) -> FusedReference:
    """Fuse GNSS (ENU positions, speed, course) and an IMU yaw rate on a uniform grid.

    Each GNSS fix is moved to its nearest grid point along its measured velocity (so a 10 Hz
    receiver's fixes are not smeared by up to half a grid step).
    """
    dt = float(t_grid[1] - t_grid[0])
    pos, pos_std, speed, course, head = _gridded_measurements(
        t_grid, gnss_t=gnss_t, east=east, north=north, gnss_speed=gnss_speed,
        gnss_course=gnss_course, gnss_std=gnss_std, heading_t=heading_t, heading=heading,
        settings=settings, name=name)
    moving = np.isfinite(course) & (np.nan_to_num(speed) > settings.min_course_speed_mps)
    x0, P0 = _initial_state(pos, pos_std, speed, course, head, moving, yaw_rate, dt, settings)
    q = np.array([settings.position_noise_m**2, settings.position_noise_m**2,
                  settings.gyro_noise_radps**2, settings.accel_noise_mps2**2,
                  settings.gyro_bias_walk_radps**2])
    xs, std, rejected, innov = _ekf_rts(
        np.ascontiguousarray(yaw_rate, dtype=np.float64), dt, pos, pos_std, speed, course, head,
        x0, P0, q, settings.gnss_speed_std_mps, settings.gnss_course_std_rad,
        settings.heading_std_rad, settings.min_course_speed_mps, settings.outlier_chi2)
    mirrored = False
    if not np.isfinite(head).any() and not moving.any():
        # nothing but positions tells the heading: the mirror image (-v, psi + pi) explains
        # them as well; a vehicle drives forwards most of the time
        fast = np.abs(xs[:, 3]) > 1.0
        if fast.any() and np.median(xs[fast, 3]) < 0.0:
            xs = xs.copy()
            xs[:, 2] += np.pi
            xs[:, 3] = -xs[:, 3]
            mirrored = True
    return FusedReference(
        x=xs[:, 0], y=xs[:, 1], psi=xs[:, 2], std=std[:, :3], speed=xs[:, 3],
        gyro_bias=xs[:, 4], sideslip=xs[:, 5],
        rejected={"position": int(rejected[0]), "speed": int(rejected[1]),
                  "course": int(rejected[2]), "heading": int(rejected[3])},
        position_innovation_rms_m=float(np.sqrt(innov[0] / innov[1])) if innov[1] else 0.0,
        mirrored=mirrored)


def _gridded_measurements(
        t_grid: FloatArray, *, gnss_t: FloatArray, east: FloatArray, north: FloatArray,
        gnss_speed: FloatArray | None, gnss_course: FloatArray | None,
        gnss_std: FloatArray | None, heading_t: FloatArray | None, heading: FloatArray | None,
        settings: FusionSettings,
        name: str) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The measurements on the grid: positions (N, 2), their standard deviations (the
    setting's where the receiver gives none), speed, course and heading; NaN where none."""
    n = t_grid.size
    pos = np.full((n, 2), np.nan)
    pos_std = np.full(n, settings.gnss_position_std_m)
    speed = np.full(n, np.nan)
    course = np.full(n, np.nan)
    idx = on_grid(t_grid, gnss_t, east)
    ok = idx >= 0
    if not ok.any():
        raise DataError(f"'{name}': no GNSS fix inside the drive's time span")
    shift = t_grid[idx[ok]] - gnss_t[ok]
    e, nn = east[ok].copy(), north[ok].copy()
    if gnss_speed is not None and gnss_course is not None:
        e += gnss_speed[ok] * np.cos(gnss_course[ok]) * shift
        nn += gnss_speed[ok] * np.sin(gnss_course[ok]) * shift
    pos[idx[ok], 0], pos[idx[ok], 1] = e, nn
    if gnss_std is not None:
        pos_std[idx[ok]] = np.maximum(gnss_std[ok], 0.05)
    if gnss_speed is not None:
        speed[idx[ok]] = gnss_speed[ok]
    if gnss_course is not None:
        course[idx[ok]] = gnss_course[ok]
    head = np.full(n, np.nan)
    if heading_t is not None and heading is not None:
        hidx = on_grid(t_grid, heading_t, heading)
        head[hidx[hidx >= 0]] = heading[hidx >= 0]
    return pos, pos_std, speed, course, head


def _initial_state(pos: FloatArray, pos_std: FloatArray, speed: FloatArray,
                   course: FloatArray, head: FloatArray, moving: BoolArray,
                   yaw_rate: FloatArray, dt: float,
                   settings: FusionSettings) -> tuple[FloatArray, FloatArray]:
    """The filter's start x0 and its covariance P0: the first fix, the first measured heading
    (else the first course while moving, else from the fixes' first displacement) and the
    first speed."""
    first = int(np.flatnonzero(np.isfinite(pos[:, 0]))[0])
    x0 = np.zeros(6)
    x0[0], x0[1] = pos[first]
    psi_var = np.pi**2
    if np.isfinite(head).any():
        x0[2], psi_var = head[np.isfinite(head)][0], settings.heading_std_rad**2
    elif moving.any():
        x0[2], psi_var = course[moving][0], settings.gnss_course_std_rad**2
    else:
        # positions only (a NavSatFix): the heading the vehicle first moves along, turned back
        # by what the gyro turned until then. Without it the filter may settle on the mirror
        # image (speed negative, heading turned by pi), which explains the fixes equally well.
        start = _first_heading(pos, pos_std, np.asarray(yaw_rate, dtype=np.float64), dt)
        if start is not None:
            x0[2], psi_var = start, _START_HEADING_STD_RAD**2
    x0[3] = speed[np.isfinite(speed)][0] if np.isfinite(speed).any() else 0.0
    P0 = np.diag([pos_std[first]**2, pos_std[first]**2, psi_var, 4.0, 0.01**2, 0.002**2])
    return x0, P0


#: How far the first fixes must lie apart to give a starting heading, and its uncertainty.
_START_DISTANCE_M = 5.0
_START_HEADING_STD_RAD = 0.5


def _first_heading(pos: FloatArray, pos_std: FloatArray, yaw_rate: FloatArray,
                   dt: float) -> float | None:
    """The heading at the first fix, from the first displacement of the fixes well beyond
    their noise (the direction of travel then), less what the gyro turned on the way; None if
    the fixes never move that far."""
    ok = np.flatnonzero(np.isfinite(pos[:, 0]))
    first = ok[0]
    reach = max(_START_DISTANCE_M, 4.0 * float(pos_std[first]))
    dist = np.hypot(pos[ok, 0] - pos[first, 0], pos[ok, 1] - pos[first, 1])
    far = np.flatnonzero(dist > reach)
    if far.size == 0:
        return None
    j = ok[far[0]]
    # the chord's direction is the heading half way along it (a steady turn)
    turned = float(np.sum(yaw_rate[first:(first + j) // 2])) * dt
    return float(np.arctan2(pos[j, 1] - pos[first, 1], pos[j, 0] - pos[first, 0])) - turned
