"""Figures as PNG bytes: a sensor trace with its detected pulses marked.

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
    y = np.asarray(samples, dtype=float)
    t = t0 + dt * np.arange(y.size)
    tt, yy = _decimate(t, y)
    scale, unit = _time_scale(t[-1] - t[0] if y.size > 1 else dt)
    features = dict(features or {})
    with _LOCK:
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
        note = _summary(features)
        if note:
            ax.text(0.99, 0.97, note, transform=ax.transAxes, ha="right", va="top", fontsize=8,
                    family="monospace", bbox={"fc": "white", "ec": "0.8", "alpha": 0.9})
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
    return buf.getvalue()


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
