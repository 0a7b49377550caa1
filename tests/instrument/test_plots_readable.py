"""Plots people can read: the trace's legend and summary never cover a marked peak, however the
pulses sit; labels placed near one another are moved apart until none overlaps another; hollow
map markers keep a dark outline a pale colour shows against; every axis label states its unit
(``(-)`` for a dimensionless one)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from service_support import DT, shot_samples

from solitonde.instrument.plotting import map_figure, map_png, spread_labels, trace_figure
from solitonde.signal.features import extract
from solitonde.signal.waveform import Waveform


@pytest.mark.parametrize("flip", [False, True])
def test_the_legend_and_summary_never_cover_a_marked_peak(flip):
    samples = shot_samples()
    if flip:  # the reflection where the legend used to stand: early and tall
        samples = samples[::-1].copy()
    features = extract(Waveform(samples=samples, t0=0.0, dt=DT, units="N")).to_dict()
    fig = trace_figure(0.0, DT, samples, features)
    ax = fig.axes[0]
    renderer = fig.canvas.get_renderer()
    boxes = [ax.get_legend().get_window_extent(renderer)]
    boxes += [t.get_window_extent(renderer) for t in ax.texts]
    peaks = []
    for which in ("incident", "reflected"):
        ts, amp = features[f"{which}_time_s"], features[f"{which}_peak_N"]
        if ts is not None and amp is not None:
            scale = 1e3  # the trace spans ms
            peaks.append(ax.transData.transform((ts * scale, amp + features.get("baseline_N", 0))))
    assert peaks
    for x, y in peaks:
        assert not any(b.contains(x, y) for b in boxes), (x, y)
    axes_box = ax.get_window_extent(renderer)
    assert not any(b.overlaps(axes_box) for b in boxes), "legend or summary inside the axes"


def test_labels_near_one_another_are_moved_apart():
    fig = Figure(figsize=(4, 3), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    points = [(1.0, 1.0), (1.01, 1.0), (1.02, 1.01), (1.0, 1.02), (1.5, 1.5)]
    ax.set_xlim(0.8, 1.8)
    ax.set_ylim(0.8, 1.8)
    labels = [ax.annotate(f"resolved 24x24x1 p{k}", p, textcoords="offset points", xytext=(4, 2),
                          fontsize=7) for k, p in enumerate(points)]
    renderer = fig.canvas.get_renderer()

    def overlapping() -> int:
        boxes = [t.get_window_extent(renderer) for t in labels]
        return sum(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])

    assert overlapping() > 0  # as placed, they print over one another
    spread_labels(ax, labels)
    assert overlapping() == 0


def test_a_map_draws_hollow_markers_over_a_dark_outline():
    from matplotlib.colors import to_rgba

    def position(name, x, status):
        est = {"status": status, "median": None if status != "constrained" else 3e-3,
               "ci95": [2e-3, None] if status == "lower_bound_only" else [2.9e-3, 3.1e-3]}
        return {"position": name, "x_m": x, "y_m": 0.2, "n_shots": 3, "thickness_m": est,
                "distance_m": est}

    plate = {"plate_id": "P", "plate_size_m": [0.9, 0.9], "support": None,
             "positions": [position("A", 0.1, "constrained"),
                           position("B", 0.3, "lower_bound_only"),
                           position("C", 0.5, "lower_bound_only")]}
    fig = map_figure(plate)
    for ax in fig.axes[:2]:
        hollow = [c for c in ax.collections if len(c.get_facecolors()) == 0
                  or c.get_facecolors()[0][3] == 0]
        at = {}
        for c in hollow:
            at.setdefault(tuple(np.round(c.get_offsets()[0], 6)), []).append(c)
        assert len(at) == 2, at.keys()  # B and C
        for layers in at.values():
            widths = [c.get_linewidths()[0] for c in layers]
            under = layers[int(np.argmax(widths))]
            assert tuple(under.get_edgecolors()[0]) == to_rgba("black")
            assert under.get_zorder() < layers[int(np.argmin(widths))].get_zorder()
    assert map_png(plate).startswith(b"\x89PNG")


def test_every_axis_label_states_its_unit():
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2] / "instrument"
    missing = []
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr in ("set_xlabel", "set_ylabel") and node.args):
                arg = node.args[0]
                text = arg.value if isinstance(arg, ast.Constant) else ast.unparse(arg)
                if not re.search(r"\(.+\)|, (mm|m|s|N|kHz)\b|unit", str(text)):
                    missing.append(f"{path.name}: {text}")
    assert not missing, missing


def test_a_trace_png_still_renders():
    from solitonde.instrument.plotting import trace_png

    png = trace_png(0.0, DT, shot_samples(), None)
    assert png.startswith(b"\x89PNG") and np.frombuffer(png[:8], np.uint8).size == 8
