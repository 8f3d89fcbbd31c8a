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
from matplotlib.ticker import FixedFormatter, FixedLocator, MaxNLocator, NullLocator
from numpy.typing import NDArray

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.model.parameters import PARAMETER_DISPLAY, PARAMETER_NAMES
from odocal.report.style import CALIBRATED, DATASHEET, FITTED_ALT, RAW, REFERENCE, STEP1

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
    ax.set_axisbelow(True)
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
    """Mean position error on each validation segment, per parameter set, on a linear axis
    from zero: one bar twice as long as another is twice the error."""
    order = [k for k in ("datasheet", "raw", "calibrated") if k in errors]
    colours = {"datasheet": DATASHEET, "raw": RAW, "calibrated": CALIBRATED}
    labels = {"datasheet": "datasheet values", "raw": "batch G-N, measured rates",
              "calibrated": "calibrated"}
    n = errors[order[0]].size
    width = 0.8 / len(order)
    x = np.arange(1, n + 1)
    artists: list[Any] = [bars(ax, x + (i - (len(order) - 1) / 2) * width, errors[k],
                               width=width, color=colours[k],
                               label=f"{labels[k]} (mean {errors[k].mean():.2f} m)")
                          for i, k in enumerate(order)]
    top = max((float(np.nanmax(e)) for e in errors.values() if np.isfinite(e).any()),
              default=1.0)
    ax.set_ylim(0.0, 1.3 * top if top > 0 else 1.0)      # head room for the legend
    ax.set_xlim(0.4, n + 0.6)
    ax.xaxis.set_major_locator(MaxNLocator(nbins="auto", integer=True))
    ax.set_ylabel("mean position error [m]")
    ax.set_title("Validation error per segment (linear scale from 0)", fontsize=9)
    ax.set_axisbelow(True)                        # the grid behind the bars, not across them
    ax.legend(fontsize=8, ncol=len(order), loc="upper center")
    ax.grid(True, axis="y", alpha=0.3)
    return artists


#: Ratios are drawn no lower than this (a noise-free calibration's error is ~0): a marker
#: pointing down stands for "this or less".
RATIO_FLOOR = 1e-4
#: Where a ratio axis may put its ticks, finest first: the first that puts at most
#: :data:`_MAX_TICKS` in the range is used.
_DECADES = 10.0 ** np.arange(0, 5)
_RATIO_TIERS = tuple(np.unique(np.concatenate([m * _DECADES for m in mantissas]
                                              + [1 / (m * _DECADES) for m in mantissas]))
                     for mantissas in ((1.0, 2.0, 3.0, 5.0), (1.0, 3.0), (1.0,)))
_MAX_TICKS = 7


def ratio_label(value: float) -> str:
    """A ratio as a reader says it: ``1/50``, ``1``, ``3``."""
    if value <= 0 or not np.isfinite(value):
        return "0"
    magnitude = 1 / value if value < 1 else value
    digits = f"{magnitude:.3g}" if magnitude < 1000 else f"{magnitude:.0f}"
    return f"1/{digits}" if value < 1 else digits


def ratio_axis(ax: Axes, values: FloatArray, *, include: Sequence[float] = (1.0,)) -> None:
    """A log axis for ratios, spanning ``values`` and ``include``, with ticks labelled as
    fractions (1/100 .. 1/3, 1, 3 ..): equal steps are equal factors."""
    finite = np.asarray(values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    low = min([*(np.maximum(finite, RATIO_FLOOR).tolist()), *include])
    high = max([*(finite.tolist()), *include])
    low, high = low / 1.8, high * 1.8
    ax.set_yscale("log")
    ax.set_ylim(low, high)
    for tier in _RATIO_TIERS:
        ticks = tier[(tier >= low) & (tier <= high)]
        if ticks.size <= _MAX_TICKS:
            break
    ax.yaxis.set_major_locator(FixedLocator(ticks))
    ax.yaxis.set_major_formatter(FixedFormatter([ratio_label(t) for t in ticks]))
    ax.yaxis.set_minor_locator(NullLocator())


def _floored(ax: Axes, x: FloatArray, values: FloatArray, *, colour: str, marker: str,
             label: str | None, size: float = 24.0) -> list[Any]:
    """Markers at ``values`` (log axis); those below :data:`RATIO_FLOOR` at the floor, pointing
    down."""
    ok = np.isfinite(values)
    low = ok & (values < RATIO_FLOOR)
    shown = ok & ~low
    artists: list[Any] = [ax.scatter(x[shown], values[shown], s=size, color=colour,
                                     marker=marker, label=label, zorder=3)]
    if low.any():
        artists.append(ax.scatter(x[low], np.full(int(low.sum()), RATIO_FLOOR), s=size,
                                  color=colour, marker="v", zorder=3,
                                  label=None if shown.any() else label))
    return artists


def plot_error_ratio(ax: Axes, errors: dict[str, FloatArray]) -> list[Any]:
    """Each validation segment's error with the calibrated (and raw) parameters as a fraction
    of the datasheet values' error on the same segment (log scale: 1/10 and 10 are equally far
    from 1; below the line at 1 the calibration does better)."""
    base = errors["datasheet"]
    n = base.size
    x = np.arange(1, n + 1, dtype=np.float64)
    artists: list[Any] = [ax.axhline(1.0, color=REFERENCE, lw=1, ls="--",
                                     label="as large as with the datasheet values")]
    shown = []
    with np.errstate(divide="ignore", invalid="ignore"):
        for k, colour, marker, dx in (("raw", RAW, "D", -0.12), ("calibrated", CALIBRATED, "o",
                                                                   0.12 if "raw" in errors
                                                                   else 0.0)):
            if k not in errors:
                continue
            ratio = np.where(base > 0, errors[k] / base, np.nan)
            shown.append(ratio)
            label = ("calibrated" if k == "calibrated" else "batch G-N, measured rates") + (
                f" (median {float(np.nanmedian(ratio)):.2f} of the datasheet's)"
                if np.isfinite(ratio).any() else "")
            artists += _floored(ax, x + dx, ratio, colour=colour, marker=marker, label=label)
    ratio_axis(ax, np.concatenate(shown) if shown else np.ones(1))
    ax.set_xlim(0.4, n + 0.6)
    ax.xaxis.set_major_locator(MaxNLocator(nbins="auto", integer=True))
    ax.set_xlabel("validation segment")
    ax.set_ylabel("error / datasheet error")
    ax.legend(fontsize=8, loc="best")
    ax.grid(True, axis="y", alpha=0.3)
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


def plot_uncertainty(ax: Axes, covariance_std: FloatArray, bootstrap_std: FloatArray | None,
                     prior_std: FloatArray, identified: Sequence[bool],
                     limit_ratio: float) -> list[Any]:
    """Each standard deviation as a fraction of the datasheet uncertainty: a point per
    parameter on a log scale (a bar's length would mean nothing there), the identifiability
    limit as a line, and "not identified" where a parameter is not.

    ``limit_ratio`` is the identifiability limit as a fraction of the datasheet uncertainty.
    """
    n = len(covariance_std)
    x = np.arange(n, dtype=np.float64)
    ok = np.asarray(identified, dtype=bool)
    prior = np.asarray(prior_std, dtype=np.float64)
    rel_cov = np.where(ok, np.asarray(covariance_std) / prior, np.nan)
    dx = 0.12 if bootstrap_std is not None else 0.0
    artists: list[Any] = [ax.axhline(limit_ratio, color=DATASHEET, lw=1, ls="--",
                                     label=f"identifiability limit ({ratio_label(limit_ratio)})")]
    artists += _floored(ax, x - dx, rel_cov, colour=CALIBRATED, marker="o", label="covariance",
                        size=40.0)
    shown = [rel_cov]
    if bootstrap_std is not None:
        rel_boot = np.where(ok, np.asarray(bootstrap_std) / prior, np.nan)
        shown.append(rel_boot)
        artists += _floored(ax, x + dx, rel_boot, colour=RAW, marker="D", label="bootstrap",
                            size=32.0)
    ratio_axis(ax, np.concatenate(shown), include=(limit_ratio, 1.0))
    for j in np.flatnonzero(~ok):
        artists.append(ax.text(x[j], 0.5, "not\nidentified", ha="center", va="center",
                               fontsize=8, color="#666666", transform=ax.get_xaxis_transform()))
    ax.set_xticks(x, list(PARAMETER_NAMES))
    ax.set_xlim(-0.6, n - 0.4)
    ax.set_ylabel("std / datasheet uncertainty")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(True, axis="y", alpha=0.3)
    return artists


def plot_fitted(ax: Axes, start: FloatArray, stop: FloatArray, peak_yaw: FloatArray,
                fitted: BoolArray, cluster: IntArray,
                drives: Sequence[tuple[float, float, str]], used: FloatArray, *,
                threshold: float,
                unit: str, time_unit: str = "min", change: float | None = None) -> list[Any]:
    """What the method fitted, along the drives' time: each window or segment as a line from
    its start to its end at the height of its peak |yaw rate|, fitted ones in blue (neighbouring
    clusters alternate their shade), the others in grey; beneath, each drive's span (grey) with
    the time the fit used (blue).

    start, stop : (N,) where each window or segment lies on the axis (``time_unit``)
    drives : (start, stop, name) of each drive on the axis
    used : (M, 2) the time the fit used, as disjoint (start, stop) spans on the axis
    change : where a change inside the log was found (the fit is of the part after it)
    """
    peak = np.asarray(peak_yaw, dtype=np.float64)
    top = max(float(peak.max()) if peak.size else 0.0, 1.5 * threshold)
    artists = _fitted_lines(ax, start, stop, peak, fitted, cluster, unit=unit)
    artists.append(ax.axhline(threshold, color=DATASHEET, lw=1, ls="--",
                              label=f"bends: above {threshold:g} rad/s"))
    # the drives' spans, and the time the fit used, as a strip beneath
    strip = -0.08 * top
    artists += _drive_strip(ax, drives, used, strip=strip, top=top)
    if change is not None:
        artists.append(ax.axvline(change, color=DATASHEET, lw=1.4,
                                  label="change inside the log"))
    ends = [b for _, b, _ in drives] or [float(stop.max()) if stop.size else 1.0]
    begins = [a for a, _, _ in drives] or [0.0]
    span = max(max(ends) - min(begins), 1e-9)
    ax.set_xlim(min(begins) - 0.01 * span, max(ends) + 0.01 * span)
    ax.set_ylim(2.0 * strip, top * (1.18 if len(drives) > 1 else 1.08))
    ax.set_xlabel(f"time [{time_unit}]" + (", the drives one after another"
                                           if len(drives) > 1 else ""))
    ax.set_ylabel("peak |yaw rate| [rad/s]")
    # above the axes: the drives' names take the top of the panel
    ax.legend(fontsize=8, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=4, frameon=False)
    ax.grid(True, axis="y", alpha=0.3)
    return artists


def _fitted_lines(ax: Axes, start: FloatArray, stop: FloatArray, peak: FloatArray,
                  fitted: BoolArray, cluster: IntArray, *, unit: str) -> list[Any]:
    """Each window or segment as a line at the height of its peak |yaw rate|, fitted ones in
    blue (neighbouring clusters alternate their shade), the others in grey; with their legend
    entries."""
    from matplotlib.collections import LineCollection

    artists: list[Any] = []
    # a shade per cluster, alternating: where one cluster ends and the next begins shows
    labels = np.unique(cluster[fitted]) if fitted.any() else np.zeros(0, dtype=np.int64)
    parity = np.searchsorted(labels, cluster) % 2 if labels.size else np.zeros(peak.size, int)
    colours = np.where(~fitted, STEP1, np.where(parity == 0, CALIBRATED, FITTED_ALT))
    segments = np.stack([np.column_stack([start, peak]), np.column_stack([stop, peak])], axis=1)
    order = np.argsort(fitted, kind="stable")            # grey first, blue drawn over it
    lines = LineCollection(list(segments[order]), colors=colours[order], linewidths=2.2,
                           capstyle="round")
    ax.add_collection(lines)
    artists.append(lines)
    fitted_count, other = int(fitted.sum()), int((~fitted).sum())
    # legend entries (the collection has one colour per line)
    artists.append(ax.plot([], [], color=CALIBRATED, lw=2.2,
                           label=f"fitted: {fitted_count} {unit}s in {labels.size} "
                                 "clusters (shades alternate)")[0])
    if other:
        artists.append(ax.plot([], [], color=STEP1, lw=2.2,
                               label=f"not fitted: {other} {unit}s")[0])
    return artists


def _drive_strip(ax: Axes, drives: Sequence[tuple[float, float, str]], used: FloatArray, *,
                 strip: float, top: float) -> list[Any]:
    """At height ``strip`` beneath the lines, each drive's span (grey) and the time the fit
    used (blue); with several drives, each one's start marked and named at ``top``."""
    from matplotlib.collections import LineCollection

    artists: list[Any] = []
    for a, b, name in drives:
        artists.append(ax.hlines(strip, a, b, color="#cccccc", lw=6))
        if len(drives) > 1:
            artists.append(ax.axvline(a, color="#bbbbbb", lw=0.8))
            artists.append(ax.text(a, top * 1.02, f" {name}", fontsize=7, color="#555555",
                                   va="bottom", clip_on=True))
    if len(used):
        artists.append(ax.add_collection(LineCollection(
            [((a, strip), (b, strip)) for a, b in used], colors=CALIBRATED, linewidths=6)))
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
    ax.set_ylabel(f"{name} [{unit}]" if unit else name)
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
    ax.set_ylabel(f"{name} [{unit}]" if unit else name)
    ax.grid(True, alpha=0.3)
    return artists
