"""Small helpers for the reproduction and benchmark figures: Agg canvases, atomic PNG/CSV writes.

matplotlib's object API on the Agg canvas (no pyplot state), as in :mod:`.plotting`. Every file is
written to a temporary name in the target folder and renamed, so a reader never sees half a file.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from solitonde.signal import atomic
from solitonde.signal.json_ready import json_ready

DPI = 90
"""Resolution of the PNGs: small files (tens of kB) that still read well in a README."""

PLATE_COLOURS = {2.29e-3: "tab:red", 3.18e-3: "tab:green", 4.83e-3: "tab:blue"}
DIAMETER_MARKERS = {4.76e-3: "o", 9.53e-3: "s", 19.05e-3: "^"}


def new_figure(ncols: int = 1, width: float = 6.4, height: float = 4.0) -> tuple[Figure, Any]:
    """A figure with ``ncols`` axes side by side (the axes, or an array of them)."""
    fig = Figure(figsize=(width * (1 if ncols == 1 else 0.8 * ncols), height), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, ncols)
    return fig, axes


def write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_bytes(path, data)


def save_png(fig: Figure, path: Path) -> None:
    """Render ``fig`` as PNG to ``path``."""
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    write_bytes(path, buf.getvalue())


def save_csv(frame: pd.DataFrame, path: Path) -> None:
    """Write a table as CSV (full float precision, no index)."""
    write_bytes(path, frame.to_csv(index=False, float_format="%.10g").encode())


def save_json(data: Any, path: Path) -> None:
    """Write JSON (NaN becomes null so any JSON reader accepts the file)."""
    write_bytes(path, (json.dumps(json_ready(data), indent=2) + "\n").encode())
