"""The report's figures. Each function draws on the axes it is given and returns what it drew.

Bars are drawn as one collection per series rather than one artist per bar, and long lines are
thinned to what a figure's pixels can show: a one-hour drive's figures render in a fraction of a
second and look the same.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from matplotlib.ticker import MaxNLocator
from numpy.typing import NDArray

from odocal.model.parameters import PARAMETER_DISPLAY, PARAMETER_NAMES
from odocal.report.style import CALIBRATED, DATASHEET, RAW, REFERENCE, STEP1

FloatArray = NDArray[np.float64]
#: Display scale and unit of each parameter (c_d and d read best in mm).
DISPLAY = PARAMETER_DISPLAY


#: Points a line keeps at most (a figure is at most ~1100 pixels wide).
MAX_LINE_POINTS = 2000


def thin(points: FloatArray, limit: int = MAX_LINE_POINTS) -> FloatArray:
    """Every k-th row of ``points`` (first and last kept) so that at most ``limit`` remain."""
    n = points.shape[0]
    if n <= limit:
        return points
    index = np.unique(np.concatenate([np.arange(0, n, -(-n // limit)), [n - 1]]))
    return points[index]


def bars(ax: Axes, x: NDArray[Any], heights: NDArray[Any], *, width: float | FloatArray,
         color: str | Sequence[str], label: str | None = None, bottom: float = 0.0,
         align: str = "center") -> PolyCollection:
    """Bars as one collection (the look of ``ax.bar``, one artist for all of them)."""
    x = np.asarray(x, dtype=np.float64)
    h = np.asarray(heights, dtype=np.float64)
    w = np.broadcast_to(np.asarray(width, dtype=np.float64), x.shape)
    left = x - w / 2 if align == "center" else x
    ok = np.isfinite(h)
    verts = [((a, bottom), (a, top), (a + b, top), (a + b, bottom))
             for a, b, top in zip(left[ok], w[ok], h[ok], strict=True)]
    colours = np.asarray(color, dtype=object)[ok] if not isinstance(color, str) else color
    collection = PolyCollection(verts, facecolors=colours, edgecolors="none", label=label)
    ax.add_collection(collection)
    if ok.any():
        ax.update_datalim([(float(left[ok].min()), bottom),
                           (float((left + w)[ok].max()), float(h[ok].max()))])
        ax.autoscale_view()
    return collection


def plot_map(ax: Axes, reference: FloatArray, datasheet: FloatArray, calibrated: FloatArray, *,
             title: str) -> list[Any]:
    """Reference and dead-reckoned trajectories of one segment, positions in metres."""
    origin = reference[0]
    reference, datasheet, calibrated = thin(reference), thin(datasheet), thin(calibrated)
    artists = [
        ax.plot(*(reference - origin).T, color=REFERENCE, lw=2.2, label="reference")[0],
        ax.plot(*(datasheet - origin).T, color=DATASHEET, lw=1.4, ls="--",
                label="datasheet parameters")[0],
        ax.plot(*(calibrated - origin).T, color=CALIBRATED, lw=1.4, label="calibrated")[0],
        ax.plot(0, 0, "o", color=REFERENCE, ms=5)[0],
    ]
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=9)
    ax.grid(True, alpha=0.3)
    return artists


def plot_step1_sorted(ax: Axes, sorted_errors: FloatArray, picked_ranks: Sequence[int], *,
                      final_m: float | None, raw_m: float | None) -> list[Any]:
    """Fig. 4: validation errors of the step-1 batches, sorted, the picked ones marked."""
    ranks = np.arange(1, sorted_errors.size + 1)
    colours = [CALIBRATED if i in set(picked_ranks) else STEP1 for i in range(sorted_errors.size)]
    artists: list[Any] = [bars(ax, ranks, sorted_errors, color=colours, width=0.8)]
    if final_m is not None:
        artists.append(ax.axhline(final_m, color=CALIBRATED, lw=1.5,
                                  label=f"three-step calibration {final_m:.2f} m"))
    if raw_m is not None:
        artists.append(ax.axhline(raw_m, color=RAW, lw=1.5, ls="--",
                                  label=f"batch G-N on all segments {raw_m:.2f} m"))
    ax.set_xlabel("step-1 batch, sorted by validation error")
    ax.xaxis.set_major_locator(MaxNLocator(nbins="auto", integer=True))
    ax.set_ylabel("validation error E_p [m]")
    ax.set_title("Step 1: batch G-N on measured rates (picked sets in blue)", fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(True, axis="y", alpha=0.3)
    return artists


def plot_parameter_spread(axes: Sequence[Axes], step1: FloatArray, picked: Sequence[int],
                          estimates: Sequence[tuple[str, FloatArray, FloatArray, str]],
                          datasheet: FloatArray) -> list[Any]:
    """Fig. 5/7: every step-1 batch's parameters, and the final estimates with one std."""
    artists: list[Any] = []
    for j, (ax, name) in enumerate(zip(axes, PARAMETER_NAMES, strict=True)):
        scale, unit = DISPLAY[name]
        jitter = np.linspace(-0.15, 0.15, step1.shape[0]) if step1.shape[0] else np.zeros(0)
        artists.append(ax.scatter(jitter, step1[:, j] * scale, s=10, color=STEP1,
                                  label="step-1 batches"))
        if len(picked):
            artists.append(ax.scatter(jitter[list(picked)], step1[list(picked), j] * scale, s=22,
                                      color=CALIBRATED, marker="s", label="picked for step 2"))
        for i, (label, theta, std, colour) in enumerate(estimates):
            artists.append(ax.errorbar([0.5 + 0.25 * i], [theta[j] * scale], yerr=[std[j] * scale],
                                       fmt="o", color=colour, capsize=3, label=label))
        artists.append(ax.axhline(datasheet[j] * scale, color=DATASHEET, lw=1, ls=":",
                                  label="datasheet"))
        ax.set_xticks([])
        ax.set_xlim(-0.4, 0.5 + 0.25 * len(estimates))
        ax.set_title(f"{name} [{unit}]", fontsize=9)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    return artists


def plot_rates(ax: Axes, t: FloatArray, measured: FloatArray, compensated: FloatArray
               ) -> list[Any]:
    """Fig. 6: measured and compensated wheel rates of one segment (rev/s)."""
    artists = []
    for i, (side, colour) in enumerate((("rear left", "#2ca02c"), ("rear right", "#9467bd"))):
        artists.append(ax.plot(t, measured[:, i], color=colour, lw=0.8, alpha=0.5,
                               label=f"{side}, measured")[0])
        artists.append(ax.plot(t, compensated[:, i], color=colour, lw=1.6,
                               label=f"{side}, compensated")[0])
    ax.set_xlabel("time in segment [s]")
    ax.set_ylabel("wheel rotation rate [rev/s]")
    ax.set_title("Step 2: measured and compensated wheel rates", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(True, alpha=0.3)
    return artists


def plot_segment_errors(ax: Axes, errors: dict[str, FloatArray]) -> list[Any]:
    """Fig. 8: validation error of each validation segment, per parameter set."""
    order = [k for k in ("datasheet", "raw", "calibrated") if k in errors]
    colours = {"datasheet": DATASHEET, "raw": RAW, "calibrated": CALIBRATED}
    labels = {"datasheet": "datasheet", "raw": "batch G-N, measured rates",
              "calibrated": "calibrated"}
    n = errors[order[0]].size
    width = 0.8 / len(order)
    x = np.arange(1, n + 1)
    positive = np.concatenate([e[e > 0] for e in errors.values()])
    floor = 10.0 ** np.floor(np.log10(positive.min())) if positive.size else 1e-3
    ax.set_yscale("log")
    artists = [bars(ax, x + (i - (len(order) - 1) / 2) * width, np.maximum(errors[k], floor),
                    width=width, color=colours[k], bottom=floor,
                    label=f"{labels[k]} (mean {errors[k].mean():.2f} m)")
               for i, k in enumerate(order)]
    ax.set_xlabel("validation segment")
    ax.xaxis.set_major_locator(MaxNLocator(nbins="auto", integer=True))
    ax.set_ylabel("mean position error [m]")
    low, high = ax.get_ylim()
    ax.set_ylim(low, high * 10)                   # head room for the legend on the log scale
    ax.set_title("Validation error per segment", fontsize=9)
    ax.legend(fontsize=8, ncol=len(order), loc="upper center")
    ax.grid(True, axis="y", alpha=0.3, which="both")
    return artists


def plot_histogram(ax: Axes, seconds: FloatArray, edges: FloatArray, *, xlabel: str,
                   marks: Sequence[float] = (), mark_label: str = "") -> list[Any]:
    """Time spent in each bin (s)."""
    artists: list[Any] = [bars(ax, edges[:-1], seconds, width=np.diff(edges) * 0.94,
                               color="#8da0cb", align="edge")]
    for i, m in enumerate(marks):
        artists.append(ax.axvline(m, color=DATASHEET, lw=1, ls="--",
                                  label=mark_label if i == 0 else None))
    if marks and mark_label:
        ax.legend(fontsize=8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("time [s]")
    ax.grid(True, axis="y", alpha=0.3)
    return artists


def plot_selection(ax: Axes, peak_yaw: FloatArray, threshold: float) -> list[Any]:
    """Peak yaw rate of every identification segment against the selection threshold."""
    selected = peak_yaw > threshold
    idx = np.arange(peak_yaw.size)
    artists = [ax.scatter(idx[selected], peak_yaw[selected], s=6, color=CALIBRATED,
                          label=f"selected ({int(selected.sum())})"),
               ax.scatter(idx[~selected], peak_yaw[~selected], s=6, color=STEP1,
                          label=f"too straight ({int((~selected).sum())})"),
               ax.axhline(threshold, color=DATASHEET, lw=1, ls="--",
                          label=f"threshold {threshold} rad/s")]
    ax.set_xlabel("identification segment")
    ax.xaxis.set_major_locator(MaxNLocator(nbins="auto", integer=True))
    ax.set_ylabel("peak |yaw rate| [rad/s]")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return artists


def plot_uncertainty(ax: Axes, covariance_std: FloatArray, bootstrap_std: FloatArray | None,
                     prior_std: FloatArray, identified: Sequence[bool],
                     limit_ratio: float) -> list[Any]:
    """Standard deviations relative to the datasheet uncertainty (log scale).

    ``limit_ratio`` is the identifiability limit as a fraction of the datasheet uncertainty.
    """
    x = np.arange(len(covariance_std))
    ok = np.array(identified)
    rel_cov = np.where(ok, covariance_std / prior_std, np.nan)
    artists: list[Any] = [ax.bar(x - 0.2, rel_cov, width=0.4, color=CALIBRATED,
                                 label="covariance")]
    if bootstrap_std is not None:
        artists.append(ax.bar(x + 0.2, np.where(ok, bootstrap_std / prior_std, np.nan),
                              width=0.4, color=RAW, label="bootstrap"))
    artists.append(ax.axhline(limit_ratio, color=DATASHEET, lw=1, ls="--",
                              label="identifiability limit"))
    ax.set_xticks(x, list(PARAMETER_NAMES))
    ax.set_yscale("log")
    ax.set_ylabel("standard deviation / datasheet uncertainty")
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", alpha=0.3, which="both")
    return artists


def plot_inverse_fit(ax: Axes, measured: FloatArray, residual: FloatArray, *,
                     channel: int) -> list[Any]:
    """Measured window revolutions against those the reference motion implies (one channel).

    ``channel`` 0: distance (mean of the two wheels); 1: yaw (right minus left).
    """
    implied = measured[:, channel] - residual[:, channel]
    pts = thin(np.column_stack([implied, measured[:, channel]]), 4000)
    lo, hi = float(np.min(pts)), float(np.max(pts))
    name = ("distance: mean of both wheels" if channel == 0
            else "yaw: right minus left wheel")
    artists = [ax.scatter(pts[:, 0], pts[:, 1], s=3, color=CALIBRATED, alpha=0.5,
                          label="windows"),
               ax.plot([lo, hi], [lo, hi], color=REFERENCE, lw=1, label="measured = implied")[0]]
    ax.set_xlabel("revolutions the reference motion implies [rev]")
    ax.set_ylabel("measured revolutions [rev]")
    ax.set_title(name, fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(True, alpha=0.3)
    return artists


def legend(ax: Axes, **kwargs: Any) -> list[Any]:
    """The axes' legend (for figures whose first panel carries it)."""
    return [ax.legend(**kwargs)]


def plot_trace(ax: Axes, distance_km: FloatArray, value: FloatArray, std: FloatArray,
               identified: FloatArray, *, name: str, batch: float | None = None,
               batch_std: float | None = None, alarms_km: Sequence[float] = ()) -> list[Any]:
    """One parameter of an online calibration against distance, with its one-sigma band."""
    scale, unit = DISPLAY[name]
    ok = np.asarray(identified, dtype=bool)
    v, s = np.asarray(value) * scale, np.asarray(std) * scale
    artists: list[Any] = []
    if ok.any():
        artists.append(ax.fill_between(distance_km, np.where(ok, v - s, np.nan),
                                       np.where(ok, v + s, np.nan), color=CALIBRATED, alpha=0.25,
                                       lw=0, label="online, one std"))
    artists.append(ax.plot(distance_km, np.where(ok, v, np.nan), color=CALIBRATED, lw=1.4,
                           label="online estimate")[0])
    if batch is not None:
        artists.append(ax.axhline(batch * scale, color=RAW, lw=1.2, ls="--",
                                  label="batch (whole log)"))
        if batch_std:
            artists.append(ax.axhspan((batch - batch_std) * scale, (batch + batch_std) * scale,
                                      color=RAW, alpha=0.12, lw=0))
    for i, km in enumerate(alarms_km):
        artists.append(ax.axvline(km, color=DATASHEET, lw=1.2,
                                  label="change detected" if i == 0 else None))
    ax.set_xlabel("distance driven [km]")
    ax.set_ylabel(f"{name} [{unit}]")
    ax.grid(True, alpha=0.3)
    return artists


def plot_history(ax: Axes, days: FloatArray, value: FloatArray, std: FloatArray,
                 identified: FloatArray, *, name: str,
                 baselines: Sequence[tuple[float, ...]] = (),
                 alarms: Sequence[float] = (), events: Sequence[float] = (),
                 xlabel: str = "days") -> list[Any]:
    """One parameter of one vehicle over its drives: estimates with one-std bars (hollow where
    not identified), baselines (from, to, value, band) and alarms and declared events."""
    scale, unit = DISPLAY[name]
    ok = np.asarray(identified, dtype=bool)
    v, s = np.asarray(value) * scale, np.asarray(std) * scale
    artists: list[Any] = []
    artists.append(ax.errorbar(days[ok], v[ok], yerr=s[ok], fmt="o", ms=3.5, color=CALIBRATED,
                               lw=1, label="drive estimate, one std"))
    if (~ok).any():
        artists.append(ax.plot(days[~ok], v[~ok], "o", ms=3.5, mfc="none", color="#999999",
                               label="not identified")[0])
    for i, (start, stop, level, band) in enumerate(baselines):
        artists.append(ax.fill_between([start, stop], (level - band) * scale,
                                       (level + band) * scale, color=STEP1, alpha=0.25, lw=0,
                                       label="baseline, with drive scatter" if i == 0 else None))
        artists.append(ax.hlines(level * scale, start, stop, color=STEP1, lw=1.2))
    for i, day in enumerate(alarms):
        artists.append(ax.axvline(day, color=DATASHEET, lw=1.3,
                                  label="change (alarm)" if i == 0 else None))
    for i, day in enumerate(events):
        artists.append(ax.axvline(day, color="#2e9b3e", lw=1.3, ls="--",
                                  label="declared event" if i == 0 else None))
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"{name} [{unit}]")
    ax.grid(True, alpha=0.3)
    return artists
