"""Figures as PNG bytes: a sensor trace with its detected pulses marked, a plate's maps.

Uses matplotlib's object API on the Agg canvas (no pyplot state), so it is safe to call from the
service's worker threads; a lock still serialises drawing because some matplotlib caches
(fonts, text layout) are shared.
"""

from __future__ import annotations

import io
import threading
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

_LOCK = threading.Lock()
_MAX_POINTS = 20_000
"""Plot at most this many points (min/max decimation keeps every peak visible)."""


def _decimate(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Min/max per bucket: a long trace drawn fast without losing its peaks."""
    if y.size <= _MAX_POINTS:
        return t, y
    buckets = _MAX_POINTS // 2
    n = (y.size // buckets) * buckets
    yb = y[:n].reshape(buckets, -1)
    tb = t[:n].reshape(buckets, -1)
    lo, hi = yb.argmin(axis=1), yb.argmax(axis=1)
    rows = np.arange(buckets)
    first = np.minimum(lo, hi)
    second = np.maximum(lo, hi)
    tt = np.column_stack([tb[rows, first], tb[rows, second]]).ravel()
    yy = np.column_stack([yb[rows, first], yb[rows, second]]).ravel()
    return tt, yy


def trace_png(
    t0: float,
    dt: float,
    samples: np.ndarray,
    features: Mapping[str, Any] | None = None,
    *,
    units: str = "N",
    title: str = "",
    width_px: int = 1000,
    height_px: int = 450,
) -> bytes:
    """Render a trace and its pulses to PNG.

    Parameters
    ----------
    t0, dt, samples:
        The trace (s, s, sensor units).
    features:
        ``Features.to_dict()`` of the trace: ``incident_time_s``/``incident_peak_N`` and
        ``reflected_time_s``/``reflected_peak_N`` are marked, secondary pulses too when listed,
        and ``tof_s``, ``arr`` and ``flags`` go in the legend.
    """
    with _LOCK:
        fig = trace_figure(t0, dt, samples, features, units=units, title=title,
                           width_px=width_px, height_px=height_px)
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
    return buf.getvalue()


def trace_figure(t0: float, dt: float, samples: np.ndarray,
                 features: Mapping[str, Any] | None = None, *, units: str = "N",
                 title: str = "", width_px: int = 1000, height_px: int = 450) -> Figure:
    """The figure :func:`trace_png` renders. The legend and the TOF/ARR summary stand to the right
    of the axes, so they never cover a marked peak, whatever the pulse shape."""
    y = np.asarray(samples, dtype=float)
    t = t0 + dt * np.arange(y.size)
    tt, yy = _decimate(t, y)
    scale, unit = _time_scale(t[-1] - t[0] if y.size > 1 else dt)
    features = dict(features or {})
    fig = Figure(figsize=(width_px / 100, height_px / 100), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(tt * scale, yy, lw=0.8, color="0.25", label="sensor")
    _mark(ax, features, "incident", "tab:blue", scale, unit)
    _mark(ax, features, "reflected", "tab:red", scale, unit)
    for k, (ts, amp) in enumerate(_secondary(features)):
        ax.axvline(ts * scale, color="tab:green", lw=0.8, ls=":",
                   label="secondary" if k == 0 else None)
        if amp is not None:
            ax.plot([ts * scale], [amp], "v", color="tab:green", ms=5)
    ax.set_xlabel(f"time ({unit})")
    ax.set_ylabel(f"sensor ({units})")
    ax.set_title(title or "sensor trace", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0.0)
    note = _summary(features)
    if note:
        ax.text(1.01, 0.45, note, transform=ax.transAxes, ha="left", va="top", fontsize=8,
                family="monospace", bbox={"fc": "white", "ec": "0.8", "alpha": 0.9})
    fig.subplots_adjust(left=0.08, right=0.78, bottom=0.13, top=0.9)
    return fig


def spread_labels(ax: Any, texts: Sequence[Any], step_pt: float = 8.0, tries: int = 12) -> None:
    """Move text labels (``ax.annotate`` with offset points) apart until none overlaps another:
    each, in turn, steps down (then up) by ``step_pt`` from its place while it overlaps one
    already placed."""
    renderer = ax.figure.canvas.get_renderer()
    placed: list[Any] = []
    for text in texts:
        x0, y0 = text.xyann
        for k in range(tries + 1):
            dy = (k + 1) // 2 * step_pt * (-1 if k % 2 else 1)
            text.xyann = (x0, y0 + dy)
            box = text.get_window_extent(renderer).expanded(1.02, 1.05)
            if not any(box.overlaps(other) for other in placed):
                break
        placed.append(text.get_window_extent(renderer))


def _time_scale(span: float) -> tuple[float, str]:
    if span < 2e-3:
        return 1e6, "µs"
    if span < 2.0:
        return 1e3, "ms"
    return 1.0, "s"


def _number(value: Any) -> float | None:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if np.isfinite(x) else None


def _mark(ax: Any, features: Mapping[str, Any], which: str, color: str, scale: float,
          unit: str) -> None:
    ts = _number(features.get(f"{which}_time_s"))
    if ts is None:
        return
    ax.axvline(ts * scale, color=color, lw=1.0, ls="--", label=f"{which} {ts * scale:.4g} {unit}")
    amp = _number(features.get(f"{which}_peak_N"))
    if amp is not None:
        # peaks are reported above the baseline; the trace is drawn as recorded
        ax.plot([ts * scale], [amp + (_number(features.get("baseline_N")) or 0.0)], "o",
                color=color, ms=5)


def _secondary(features: Mapping[str, Any]) -> list[tuple[float, float | None]]:
    """Secondary pulses in whichever shape the features list them."""
    out: list[tuple[float, float | None]] = []
    items = features.get("secondary") or features.get("secondary_pulses") or []
    if isinstance(items, Sequence) and not isinstance(items, str):
        for item in items:
            if isinstance(item, Mapping):
                ts = _number(item.get("time_s"))
                amp = _number(item.get("peak_N", item.get("amplitude_N")))
            else:
                ts, amp = _number(item), None
            if ts is not None:
                out.append((ts, amp))
    times = features.get("secondary_times_s")
    if isinstance(times, Sequence) and not isinstance(times, str):
        out.extend((t, None) for t in (_number(x) for x in times) if t is not None)
    return out


def _summary(features: Mapping[str, Any]) -> str:
    lines = []
    tof = _number(features.get("tof_s"))
    if tof is not None:
        lines.append(f"TOF {tof * 1e6:.2f} µs")
    arr = _number(features.get("arr"))
    if arr is not None:
        lines.append(f"ARR {arr:.3f}")
    snr = _number(features.get("snr_db"))
    if snr is not None:
        lines.append(f"SNR {snr:.1f} dB")
    flags = features.get("flags")
    if flags:
        lines.append("flags: " + (", ".join(map(str, flags)) if not isinstance(flags, str)
                                  else flags))
    return "\n".join(lines)


_MAP_PARAMETERS = (("thickness_m", "plate thickness", "thickness", "viridis"),
                   ("distance_m", "distance to the nearest support", "distance", "plasma"))


LABELLED_POSITIONS_MAX = 40
"""A map of more positions names none of them beside its marker (they would cover each other;
the positions' table names them)."""


def map_figure(plate_map: Mapping[str, Any], *, width_px: int = 1200,
               height_px: int = 560) -> Figure:
    """Thickness and distance-to-support maps of a plate (``instrument.plate_map.build``).

    Each position is a marker coloured by its median (mm, colour bar beside each panel): filled
    when the answer is constrained; a hollow triangle pointing up ("at least") or down ("at most")
    at its 95 % bound when it is one-sided; a grey cross when there is no answer. The located
    support is drawn as a dashed line (with a joint map's opposite edge), the plate's outline
    when its size is known, the suggested next positions as numbered stars.
    """
    positions = [p for p in plate_map.get("positions", [])
                 if p.get("x_m") is not None and p.get("y_m") is not None]
    support = plate_map.get("support")
    suggestions = plate_map.get("suggestions") or []
    fig = Figure(figsize=(width_px / 100, height_px / 100), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    xs = [p["x_m"] * 1e3 for p in positions]
    ys = [p["y_m"] * 1e3 for p in positions]
    view = _MapView(positions, xs, ys, plate_map.get("plate_size_m"), support, suggestions)
    labels_of = [(ax, _map_panel(fig, ax, parameter, view))
                 for ax, parameter in zip(axes, _MAP_PARAMETERS, strict=True)]
    _map_legend(fig, support, suggestions)
    lines = _fitted_title(fig, _map_title(plate_map, len(positions), support), width_px)
    top = 0.88 - (len(lines) - 1) * 15.0 / height_px
    fig.subplots_adjust(left=0.06, right=0.97, bottom=0.16, top=top, wspace=0.25)
    for ax, labels in labels_of:  # after the layout, which moves the axes
        spread_labels(ax, labels)
    return fig


class _MapView:
    """What both panels of a plate's map draw: the positions with coordinates (mm), the
    plate's size, the located support, the suggestions, and the axes' limits."""

    def __init__(self, positions: Sequence[Mapping[str, Any]], xs: Sequence[float],
                 ys: Sequence[float], size: Sequence[float] | None,
                 support: Mapping[str, Any] | None,
                 suggestions: Sequence[Mapping[str, Any]]) -> None:
        self.positions, self.xs, self.ys = positions, xs, ys
        self.size, self.support, self.suggestions = size, support, suggestions
        xlim: tuple[float, float]
        ylim: tuple[float, float]
        if size:  # a margin, so that an edge and positions on it stay in sight
            mx, my = 0.04 * size[0] * 1e3, 0.04 * size[1] * 1e3
            xlim, ylim = (-mx, size[0] * 1e3 + mx), (-my, size[1] * 1e3 + my)
        elif positions:
            pad = max(20.0, 0.1 * max(np.ptp(xs), np.ptp(ys)))
            xlim = (min(xs) - pad, max(xs) + pad)
            ylim = (min(ys) - pad, max(ys) + pad)
        else:
            xlim = ylim = (0.0, 1.0)
        self.xlim, self.ylim = xlim, ylim


def _shown_values(positions: Sequence[Mapping[str, Any]], key: str) -> list[float]:
    """Each position's value of ``key`` in mm as its marker shows it: the median when
    constrained, the 95 % bound when one-sided, NaN when there is no answer."""
    values = []
    for p in positions:
        est = p.get(key) or {}
        status = est.get("status")
        if status == "constrained":
            values.append(est["median"] * 1e3)
        elif status == "lower_bound_only" and est.get("ci95"):
            values.append(est["ci95"][0] * 1e3)
        elif status == "upper_bound_only" and est.get("ci95"):
            values.append(est["ci95"][1] * 1e3)
        else:
            values.append(np.nan)
    return values


def _map_markers(ax: Any, view: _MapView, key: str, values: Sequence[float],
                 mappable: Any) -> None:
    """The positions' markers: filled when constrained, hollow triangles for a bound, a grey
    cross for no answer."""
    for p, v, x, y in zip(view.positions, values, view.xs, view.ys, strict=True):
        status = (p.get(key) or {}).get("status")
        if not np.isfinite(v):
            ax.plot(x, y, "x", color="0.5", ms=9, mew=2)
            continue
        colour = mappable.to_rgba(v)
        if status == "constrained":
            ax.scatter([x], [y], color=[colour], marker="o", s=160, edgecolors="black",
                       linewidths=1.0, zorder=3)
        else:  # hollow: the colour is the edge's, over a dark outline that a pale
            # colour (the map's light end) still stands out against
            marker = "^" if status == "lower_bound_only" else "v"
            ax.scatter([x], [y], marker=marker, s=170, facecolors="none",
                       edgecolors="black", linewidths=4.0, zorder=3)
            ax.scatter([x], [y], marker=marker, s=170, facecolors="none",
                       edgecolors=[colour], linewidths=2.2, zorder=4)


def _map_panel(fig: Figure, ax: Any, parameter: tuple[str, str, str, str],
               view: _MapView) -> list[Any]:
    """One panel of a plate's map (its markers, colour bar, outline, support, suggestions);
    returns the positions' labels, to be spread once the figure is laid out."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    key, label, short, cmap = parameter
    values = _shown_values(view.positions, key)
    finite = [v for v in values if np.isfinite(v)]
    vmin, vmax = (min(finite), max(finite)) if finite else (0.0, 1.0)
    if vmax - vmin < 1e-9:
        vmin, vmax = vmin - 0.5, vmax + 0.5
    mappable = ScalarMappable(Normalize(vmin, vmax), colormaps[cmap])
    _map_markers(ax, view, key, values, mappable)
    if finite:
        bar = fig.colorbar(mappable, ax=ax)
        bar.set_label(f"{short}, mm")
    if view.size:
        ax.add_patch(_outline(view.size))
    support = view.support
    if support:
        _draw_support(ax, support, view.xlim, view.ylim)
        if support.get("second_offset_m") is not None:  # the opposite clamped edge
            _draw_support(ax, {**support, "offset_m": support["second_offset_m"]}, view.xlim,
                          view.ylim)
    for k, s in enumerate(view.suggestions, start=1):
        ax.scatter([s["x_m"] * 1e3], [s["y_m"] * 1e3], marker="*", s=320, color="gold",
                   edgecolors="black", linewidths=1.2, zorder=5)
        ax.annotate(f"next {k}", (s["x_m"] * 1e3, s["y_m"] * 1e3), textcoords="offset points",
                    xytext=(8, -12), fontsize=7, color="black", zorder=6)
    positions = view.positions
    labels = [ax.annotate(str(p["position"])[:12], (x, y), textcoords="offset points",
                          xytext=(7, 7), fontsize=7, color="0.25")
              for p, x, y in zip(positions, view.xs, view.ys, strict=True) if p.get("position")
              and len(positions) <= LABELLED_POSITIONS_MAX]
    ax.set_xlim(*view.xlim)
    ax.set_ylim(*view.ylim)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x on the plate, mm")
    ax.set_ylabel("y on the plate, mm")
    ax.set_title(label)
    return labels


def _map_legend(fig: Figure, support: Mapping[str, Any] | None,
                suggestions: Sequence[Mapping[str, Any]]) -> None:
    """The markers' legend under both panels."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], marker="o", ls="", color="0.3", label="median (constrained)"),
               Line2D([], [], marker="^", ls="", mfc="none", color="0.3",
                      label="at least (95 % bound)"),
               Line2D([], [], marker="v", ls="", mfc="none", color="0.3",
                      label="at most (95 % bound)"),
               Line2D([], [], marker="x", ls="", color="0.5", label="no answer")]
    if support:
        handles.append(Line2D([], [], ls="--", color="crimson", label="located support"))
    if suggestions:
        handles.append(Line2D([], [], marker="*", ls="", color="gold", mec="black", ms=12,
                              label="measure next"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False,
               fontsize=8)


def _map_title(plate_map: Mapping[str, Any], n_positions: int,
               support: Mapping[str, Any] | None) -> str:
    """The map's title: the plate, its positions, and the support located (or why not)."""
    title = f"plate {plate_map.get('plate_id')}: {n_positions} positions"
    if plate_map.get("joint"):
        title += ", inverted jointly"
    if support:
        lo, hi = support["ci95_offset_m"]
        title += (f"; support at {support['normal_angle_deg']:.1f} deg, offset "
                  f"{support['offset_m'] * 1e3:.1f} mm (95 % {_mm(lo)}..{_mm(hi)} mm)")
    elif plate_map.get("support_reason"):
        title += f"; support not located: {plate_map['support_reason']}"
    return title


def _fitted_title(fig: Any, title: str, width_px: int) -> list[str]:
    """Set ``title`` as the figure's title wrapped to its width, never cut (a reason cut short
    says nothing); returns the lines. The width is measured as drawn, narrowing until it fits."""
    import textwrap

    renderer = FigureCanvasAgg(fig).get_renderer()
    width = max(20, int(width_px / 7))
    while True:
        lines = textwrap.wrap(title, width=width) or [""]
        text = fig.suptitle("\n".join(lines), fontsize=10)
        if text.get_window_extent(renderer).width <= 0.96 * width_px or width <= 20:
            return lines
        width = int(width * 0.9)


def map_png(plate_map: Mapping[str, Any], *, width_px: int = 1200, height_px: int = 560) -> bytes:
    """:func:`map_figure` as PNG bytes."""
    with _LOCK:
        fig = map_figure(plate_map, width_px=width_px, height_px=height_px)
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
    return buf.getvalue()


def _mm(value: float | None) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value * 1e3:.1f}"


def _outline(size: Sequence[float]) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle((0.0, 0.0), size[0] * 1e3, size[1] * 1e3, fill=False, ec="0.4", lw=1.2)


def _draw_support(ax: Any, support: Mapping[str, Any], xlim: Sequence[float],
                  ylim: Sequence[float]) -> None:
    """The line x cos(theta) + y sin(theta) = offset across the axes (mm)."""
    theta = np.radians(support["normal_angle_deg"])
    c, s, off = np.cos(theta), np.sin(theta), support["offset_m"] * 1e3
    if abs(s) < abs(c):  # more vertical than horizontal: x from y
        yy = np.array(ylim, dtype=float)
        xx = (off - yy * s) / c
    else:
        xx = np.array(xlim, dtype=float)
        yy = (off - xx * c) / s
    ax.plot(xx, yy, ls="--", color="crimson", lw=2, zorder=2)


def trace_strips(traces: Sequence[tuple[float, float, np.ndarray, Mapping[str, Any]]], *,
                 width_px: int = 760, height_px: int = 220) -> list[bytes]:
    """Small PNGs of many traces (t0, dt, samples, features), each with its incident and
    reflected pulses marked: one figure drawn again per trace (a report's hundreds of
    positions: about 30 ms a trace, a fifth of a fresh figure's time)."""
    out: list[bytes] = []
    if not traces:
        return out
    with _LOCK:
        fig = Figure(figsize=(width_px / 100, height_px / 100), dpi=100)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
        (line,) = ax.plot([], [], lw=0.7, color="0.25")
        marks = {which: (ax.axvline(0.0, color=color, lw=0.9, ls="--"),
                         ax.plot([], [], "o", color=color, ms=4)[0])
                 for which, color in (("incident", "tab:blue"), ("reflected", "tab:red"))}
        ax.set_xlabel("time (us)", fontsize=8)
        ax.set_ylabel("sensor (N)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        fig.subplots_adjust(left=0.08, right=0.99, bottom=0.2, top=0.96)
        for t0, dt, samples, features in traces:
            y = np.asarray(samples, dtype=float)
            tt, yy = _decimate(t0 + dt * np.arange(y.size), y)
            line.set_data(tt * 1e6, yy)
            for which, (vline, peak) in marks.items():
                ts = _number(features.get(f"{which}_time_s"))
                amp = _number(features.get(f"{which}_peak_N"))
                vline.set_visible(ts is not None)
                peak.set_visible(ts is not None and amp is not None)
                if ts is not None:
                    vline.set_xdata([ts * 1e6, ts * 1e6])
                    if amp is not None:
                        peak.set_data([ts * 1e6],
                                      [amp + (_number(features.get("baseline_N")) or 0.0)])
            ax.set_xlim(tt[0] * 1e6, tt[-1] * 1e6)
            low, high = float(np.min(yy)), float(np.max(yy))
            pad = 0.06 * (high - low or 1.0)
            ax.set_ylim(low - pad, high + pad)
            buf = io.BytesIO()
            fig.savefig(buf, format="png")
            out.append(buf.getvalue())
    return out
