"""Text tables as oscilloscopes, DAQ programs and spreadsheets save them.

:func:`parse` finds, in the text of a CSV-like file, the layout that wrote it, its metadata, its
time axis and its value columns (channels), with every unit scaled to seconds, volts or newtons.
It knows these layouts without hand editing:

``solitonde``
    This project's own: ``# key: value`` comment lines, then ``time_s,force_N`` (or
    ``voltage_V``) columns; or a table with no header at all.
``tektronix``
    MSO/MDO/TBS "Save Waveform": ``Key,Value`` header lines (``Horizontal Units``,
    ``Vertical Units``, ``Sample Interval`` ...), then ``TIME,CH1[,CH2...]``.
``tektronix-legacy``
    TDS/TBS/DPO: metadata in the first three columns of the first rows (``Record Length``,
    ``Vertical Units`` ...), time and value in columns 4 and 5 beside them (6 columns a channel).
``keysight``
    Keysight/Agilent InfiniiVision: ``x-axis,1[,2...]`` then a units row ``second,Volt``.
``rigol``
    ``X,CH1[,CH2...],Start,Increment`` then ``Sequence,Volt,<start>,<increment>``; the X column
    counts samples, time is start + X * increment.
``picoscope``
    ``Time,Channel A[,...]`` then a units row in brackets ``(ms),(mV)`` and a blank line; ``∞``
    marks an over-range sample.
``lecroy``
    Teledyne LeCroy: a ``LECROY...`` line, ``Segments``/``Segment`` lines, then ``Time,Ampl``.
``generic``
    Spreadsheet exports with the units in the column names: ``Time (s)``, ``time [ms]``,
    ``Voltage (mV)``, ``Force (N)``, ``force_kN``.

Comma, semicolon, tab or whitespace delimited; decimal commas where the delimiter is not a comma.
A scope's value columns with no stated unit are volts (a scope measures volts); other unlabelled
columns have no unit here, and the caller decides (its ``units=`` option). A text that fits none
of these raises :class:`~.errors.WaveformError` naming the line and what was expected.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import WaveformError
from .csv_table import (
    HEADER_LINES_MAX,
    SCOPE_LAYOUTS,
    Column,
    Table,
    assemble,
    check_length,
    count_of,
    data_start,
    dialect,
    key_values,
    labels_above,
    matrix,
    over_range,
    printed_resolution,
    read_rows,
    split_cells,
    time_scale,
    value_unit,
)


def parse(text: str, name: str) -> Table:
    """The table in ``text`` (the contents of file ``name``, for messages).

    Only the first lines (the header, at most :data:`HEADER_LINES_MAX`) and the last are
    looked at line by line; the data block goes to pandas' C parser whole, so a file of
    millions of rows costs about what reading its numbers costs.
    """
    comments: dict[str, str] = {}
    head: list[tuple[int, str, int]] = []  # (line number, text, offset) of non-blank lines
    pos, number = 0, 0
    while pos < len(text) and len(head) <= HEADER_LINES_MAX:
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        line = text[pos:end].rstrip("\r")
        number += 1
        if not head and line.startswith("#") and not _is_lecroy_segment(line):
            key, sep, value = line[1:].partition(":")
            if sep and key.strip():
                comments[key.strip()] = value.strip()
        elif line.strip():
            head.append((number, line, pos))
        pos = end + 1
    if not head:
        raise WaveformError("samples", f"{name}: empty, no samples")
    last = text.rstrip().rsplit("\n", 1)[-1].rstrip("\r")
    last_number = number if pos >= len(text) else text.count("\n", 0, len(text.rstrip())) + 1
    delimiter, decimal_comma = dialect(head, (last_number, last), name)
    cells = [(n, split_cells(line, delimiter)) for n, line, _ in head[:HEADER_LINES_MAX]]
    beside = next((read for _name, detect, read in SIDE_BY_SIDE if detect(cells)), None)
    if beside is not None:
        every = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip()
                 and i + 1 >= head[0][0]]
        table = beside([(n, split_cells(line, delimiter)) for n, line in every], decimal_comma,
                       name)
    else:
        start = data_start(cells, decimal_comma, name)
        number0, _, offset = head[start]
        table = _headed(cells[:start], text[offset:], number0, delimiter, decimal_comma, name)
    own = comments.pop("n_samples", None)
    if own is not None and table.declared_rows is None:
        table.declared_rows = count_of(own, "n_samples", name)
    table.metadata = {**comments, **table.metadata}
    check_length(table, name)
    return table


def _declared_rows(header: list[tuple[int, list[str]]], scope: dict[str, str],
                   name: str) -> int | None:
    """The record length a Tektronix or LeCroy header states; None for a gated Tektronix
    record (its length may be the whole record's) and for layouts that state none."""
    for _number, parts in header:
        if len(parts) >= 4 and parts[0] == "Segments" and parts[2] == "SegmentSize":
            return count_of(parts[1], "Segments", name) * count_of(parts[3], "SegmentSize", name)
    gating = scope.get("Gating", "0.0% to 100.0%").replace(" ", "")
    if "Record Length" in scope and gating in ("0.0%to100.0%", "0%to100%"):
        return count_of(scope["Record Length"], "Record Length", name)
    return None


@dataclass(frozen=True)
class Header:
    """What the lines above a table's data say: the lines (number, cells), the column names and
    the units row above the data (None where there are none), and the ``Key,Value`` lines."""

    lines: list[tuple[int, list[str]]]
    labels: list[str] | None
    units_row: list[str] | None
    scope: dict[str, str]

    @property
    def first_cell(self) -> str:
        return self.lines[0][1][0].lower() if self.lines and self.lines[0][1] else ""


@dataclass(frozen=True)
class Block:
    """A table's data rows as floats, some texts of its first column (their printed precision),
    the decimal mark and the file's name (for messages)."""

    data: np.ndarray
    first_texts: list[str]
    decimal_comma: bool
    name: str


@dataclass(frozen=True)
class Layout:
    """One writer's layout of a table with a header: ``detect`` tells its header from the
    others, ``parse`` makes the :class:`Table` of the data below it."""

    name: str
    detect: Callable[[Header], bool]
    parse: Callable[[Header, Block], Table]


def _columns(layout: str, header: Header, block: Block, meta: dict[str, Any]) -> Table:
    """The common case: a time column (or none) and value columns, units in the names, a units
    row or the scope's ``Vertical Units``."""
    if layout in SCOPE_LAYOUTS:
        meta["layout"] = layout
    if header.lines and header.labels is None:
        number, parts = header.lines[-1]
        raise WaveformError("file", f"{block.name} line {number}: {','.join(parts)[:80]!r} is "
                            f"not a header of {block.data.shape[1]} column names", "a header row "
                            "naming each column (time first), or a known oscilloscope layout")
    return assemble(layout, header.labels, header.units_row, block.data, header.scope, meta,
                     block.first_texts, block.decimal_comma, block.name)


def _is_lecroy(header: Header) -> bool:
    return header.first_cell.startswith("lecroy")


def _lecroy(header: Header, block: Block) -> Table:
    return _columns("lecroy", header, block,
                    {"instrument": " ".join(header.lines[0][1][:2])})


def _is_keysight(header: Header) -> bool:
    labels = header.labels or []
    return bool(labels) and labels[0].lower() == "x-axis"


def _is_rigol(header: Header) -> bool:
    return {"start", "increment"} <= {x.lower() for x in header.labels or []}


def _is_picoscope(header: Header) -> bool:
    units = header.units_row or []
    return bool(units) and all(u.startswith("(") and u.endswith(")") for u in units if u)


def _is_tektronix(header: Header) -> bool:
    labels = header.labels or []
    return bool(labels) and labels[0].lower() == "time" and (
        "vertical units" in {k.lower() for k in header.scope})


def _tektronix(header: Header, block: Block) -> Table:
    model = header.scope.get("Model") or header.scope.get("Model Number")
    return _columns("tektronix", header, block,
                    {"instrument": f"Tektronix {model}"} if model else {})


def _is_solitonde(header: Header) -> bool:
    """This project's ``time_s`` header, or a table with no header at all."""
    if header.labels is None:
        return not header.lines
    return header.labels[0].lower() in ("time_s", "t_s")


def _plain(layout: str) -> Callable[[Header, Block], Table]:
    def parse(header: Header, block: Block) -> Table:
        return _columns(layout, header, block, {})
    return parse


LAYOUTS: tuple[Layout, ...] = (
    Layout("lecroy", _is_lecroy, _lecroy),
    Layout("keysight", _is_keysight, _plain("keysight")),
    Layout("rigol", _is_rigol, lambda h, b: _rigol(h.labels or [], h.units_row, b.data, b.name)),
    Layout("picoscope", _is_picoscope, _plain("picoscope")),
    Layout("tektronix", _is_tektronix, _tektronix),
    Layout("solitonde", _is_solitonde, _plain("solitonde")),
    Layout("generic", lambda _h: True, _plain("generic")),
)
"""The layouts with a header row, in the order they are tried (the first whose ``detect``
says yes parses); ``generic`` takes what the others do not. The Tektronix legacy layout, whose
metadata sit beside the data, is told apart before any header is read
(:data:`SIDE_BY_SIDE`)."""


def _headed(lines: list[tuple[int, list[str]]], text: str, number0: int,
            delimiter: str | None, decimal_comma: bool, name: str) -> Table:
    data, first_texts = read_rows(text, number0, delimiter, decimal_comma, name)
    labels, units_row = labels_above(lines, data.shape[1])
    header = Header(lines, labels, units_row, key_values(lines))
    block = Block(data, first_texts, decimal_comma, name)
    layout = next(x for x in LAYOUTS if x.detect(header))
    table = layout.parse(header, block)
    if layout.name != "rigol":
        table.declared_rows = _declared_rows(lines, header.scope, name)
    return table


def _rigol(labels: list[str], units_row: list[str] | None, data: np.ndarray,
           name: str) -> Table:
    """Rigol: X counts samples; the units row holds the start time and the increment."""
    low = [x.lower() for x in labels]
    i_start, i_inc = low.index("start"), low.index("increment")
    if units_row is None or len(units_row) <= max(i_start, i_inc):
        raise WaveformError("file", f"{name}: a Rigol header without its start/increment row",
                            "X,CH1,Start,Increment then Sequence,Volt,<start>,<increment>")
    try:
        start, step = float(units_row[i_start]), float(units_row[i_inc])
    except ValueError:
        raise WaveformError("file", f"{name}: Rigol start/increment {units_row[i_start]!r}, "
                            f"{units_row[i_inc]!r} are not numbers") from None
    channels = [j for j in range(1, min(i_start, data.shape[1]))]
    columns = []
    for j in channels:
        unit = units_row[j] if j < len(units_row) else ""
        kind, factor = value_unit(unit, f"{name} column {labels[j]!r}") if unit else ("V", 1.0)
        columns.append(Column(labels[j], data[:, j] * factor, kind))
    time = start + data[:, 0] * step
    over_range(columns, name)
    return Table("rigol", time, columns, {"layout": "rigol"}, time_resolution=0.0)


# --- Tektronix legacy (metadata beside the data) --------------------------------------------------

_TEK_LEGACY_KEYS = ("record length", "sample interval")


def _is_tek_legacy(cells: list[tuple[int, list[str]]]) -> bool:
    parts = cells[0][1]
    return len(parts) >= 5 and parts[0].lower() in _TEK_LEGACY_KEYS


def _tek_legacy(cells: list[tuple[int, list[str]]], decimal_comma: bool, name: str) -> Table:
    """Tektronix TDS/TBS: 6 cells per channel, ``key, value, , time, value, ``."""
    width = len(cells[0][1])
    blocks = range(0, width - 4, 6)
    meta_all: list[dict[str, str]] = [{} for _ in blocks]
    rows = []
    for number, parts in cells:
        parts = parts + [""] * (width - len(parts))
        row = []
        for b, k in enumerate(blocks):
            key, value = parts[k], parts[k + 1]
            if key:
                meta_all[b][key] = value
            row.extend(parts[k + 3:k + 5])
        rows.append((number, row))
    data = matrix(rows, 2 * len(blocks), decimal_comma, name)
    time = data[:, 0] * time_scale(meta_all[0].get("Horizontal Units", "s"), name)
    columns = []
    for b, meta in enumerate(meta_all):
        label = meta.get("Source", f"CH{b + 1}")
        unit = meta.get("Vertical Units")
        kind, factor = value_unit(unit, f"{name} {label}") if unit else ("V", 1.0)
        columns.append(Column(label, data[:, 2 * b + 1] * factor, kind))
    info: dict[str, Any] = {"layout": "tektronix-legacy"}
    if meta_all[0].get("Model Number"):
        info["instrument"] = f"Tektronix {meta_all[0]['Model Number']}"
    over_range(columns, name)
    length = meta_all[0].get("Record Length")
    return Table("tektronix-legacy", time, columns, info,
                 time_resolution=printed_resolution([r[1][0] for r in rows], decimal_comma),
                 declared_rows=None if length is None else count_of(length, "Record Length", name))


SIDE_BY_SIDE: tuple[tuple[str, Callable[[list[tuple[int, list[str]]]], bool],
                          Callable[[list[tuple[int, list[str]]], bool, str], Table]], ...] = (
    ("tektronix-legacy", _is_tek_legacy, _tek_legacy),
)
"""Layouts with the metadata beside the data, as (name, detect on the first lines' cells,
parse every line's cells): tried before :data:`LAYOUTS`."""


def _is_lecroy_segment(line: str) -> bool:
    """LeCroy's ``#1,<date>,0`` segment line is data of its header, not a comment."""
    return re.match(r"^#\d+[,;\t]", line) is not None
