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

import io
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import WaveformError

TIME_UNITS = {"s": 1.0, "sec": 1.0, "second": 1.0, "seconds": 1.0, "ms": 1e-3, "us": 1e-6,
              "µs": 1e-6, "μs": 1e-6, "ns": 1e-9, "ps": 1e-12}
"""Time units found in files, lower-case, with their factor to seconds."""
VALUE_UNITS = {
    "v": ("V", 1.0), "volt": ("V", 1.0), "volts": ("V", 1.0), "mv": ("V", 1e-3),
    "uv": ("V", 1e-6), "µv": ("V", 1e-6), "μv": ("V", 1e-6), "kv": ("V", 1e3),
    "n": ("N", 1.0), "newton": ("N", 1.0), "newtons": ("N", 1.0), "kn": ("N", 1e3),
    "mn": ("N", 1e-3), "lbf": ("N", 4.4482216152605),
}
"""Value units found in files, lower-case: the project's unit (V or N) and the factor to it."""
TIME_NAMES = ("time", "t", "x-axis", "zeit", "temps", "tiempo", "tempo", "second", "seconds")
"""Column names that mean the time axis (after any unit is taken off)."""
QUANTITY_NAMES = ("force", "voltage", "volt", "signal", "amplitude", "ampl", "sensor", "value")
"""Column names whose ``_suffix`` must be a unit (``force_kN``); an unknown one is an error."""
SCOPE_LAYOUTS = ("tektronix", "tektronix-legacy", "keysight", "rigol", "picoscope", "lecroy")
OVER_RANGE = {"∞": np.inf, "+∞": np.inf, "-∞": -np.inf}
"""PicoScope writes these for a sample beyond the input range."""
_HEADER_LINES_MAX = 200
_NUMBER = re.compile(r"^[+-]?(\d+([.,]\d*)?|[.,]\d+)([eE][+-]?\d+)?$")
_LABEL_UNIT = re.compile(r"^(.*?)\s*[(\[]\s*([^)\]]*?)\s*[)\]]\s*$")


@dataclass
class Column:
    """One value column: its label in the file, its samples scaled to ``unit``, and ``unit``
    (``"V"``, ``"N"``, or None when nothing in the file says)."""

    label: str
    values: np.ndarray
    unit: str | None


@dataclass
class Table:
    """What :func:`parse` found: the layout, the time axis (seconds; None when the file has
    none), or a start and step the file states instead, the value columns and the metadata."""

    layout: str
    time: np.ndarray | None
    columns: list[Column]
    metadata: dict[str, Any] = field(default_factory=dict)
    t0: float | None = None
    dt: float | None = None
    time_resolution: float = 0.0
    """Half the last printed digit of the time column (s): rounding the grid may show."""
    declared_rows: int | None = None
    """The number of samples the header declares (Tektronix ``Record Length``, LeCroy
    ``SegmentSize``, this project's ``# n_samples``), if it declares one."""


def parse(text: str, name: str) -> Table:
    """The table in ``text`` (the contents of file ``name``, for messages).

    Only the first lines (the header, at most :data:`_HEADER_LINES_MAX`) and the last are
    looked at line by line; the data block goes to pandas' C parser whole, so a file of
    millions of rows costs about what reading its numbers costs.
    """
    comments: dict[str, str] = {}
    head: list[tuple[int, str, int]] = []  # (line number, text, offset) of non-blank lines
    pos, number = 0, 0
    while pos < len(text) and len(head) <= _HEADER_LINES_MAX:
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
    delimiter, decimal_comma = _dialect(head, (last_number, last), name)
    cells = [(n, _split(line, delimiter)) for n, line, _ in head[:_HEADER_LINES_MAX]]
    beside = next((parse for _name, detect, parse in SIDE_BY_SIDE if detect(cells)), None)
    if beside is not None:
        every = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip()
                 and i + 1 >= head[0][0]]
        table = beside([(n, _split(line, delimiter)) for n, line in every], decimal_comma, name)
    else:
        start = _data_start(cells, decimal_comma, name)
        number0, _, offset = head[start]
        table = _headed(cells[:start], text[offset:], number0, delimiter, decimal_comma, name)
    own = comments.pop("n_samples", None)
    if own is not None and table.declared_rows is None:
        table.declared_rows = _count(own, "n_samples", name)
    table.metadata = {**comments, **table.metadata}
    _check_length(table, name)
    return table


def _count(text: str, key: str, name: str) -> int:
    try:
        return int(float(text))
    except ValueError:
        raise WaveformError("file", f"{name}: {key} {text!r} is not a number",
                            "a whole number of samples") from None


def _check_length(table: Table, name: str) -> None:
    """A file with fewer rows than its header declares was cut short (a dropped link, a full
    disk): refused, since the shot's tail (often the reflection) is missing. A file cut exactly
    at a line end with no declared length cannot be told from a shorter record."""
    rows = len(table.columns[0].values) if table.columns else 0
    if table.declared_rows is not None and rows < table.declared_rows:
        raise WaveformError("file", f"{name}: {rows} data rows, its header declares "
                            f"{table.declared_rows}: the file is cut short (truncated)",
                            "the whole file as the instrument wrote it")


def _declared_rows(header: list[tuple[int, list[str]]], scope: dict[str, str],
                   name: str) -> int | None:
    """The record length a Tektronix or LeCroy header states; None for a gated Tektronix
    record (its length may be the whole record's) and for layouts that state none."""
    for _number, parts in header:
        if len(parts) >= 4 and parts[0] == "Segments" and parts[2] == "SegmentSize":
            return _count(parts[1], "Segments", name) * _count(parts[3], "SegmentSize", name)
    gating = scope.get("Gating", "0.0% to 100.0%").replace(" ", "")
    if "Record Length" in scope and gating in ("0.0%to100.0%", "0%to100%"):
        return _count(scope["Record Length"], "Record Length", name)
    return None


# --- dialect ------------------------------------------------------------------------------------


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter == "":
        return [line.strip()]
    parts = line.split() if delimiter is None else line.split(delimiter)
    parts = [p.strip().strip('"').strip() for p in parts]
    while parts and parts[-1] == "":  # a trailing delimiter (Rigol, Tektronix legacy)
        parts.pop()
    return parts


def _is_number(cell: str, decimal_comma: bool) -> bool:
    if cell in OVER_RANGE:
        return True
    if _NUMBER.match(cell) is None:
        return cell.lower() in ("nan", "inf", "+inf", "-inf", "infinity", "-infinity")
    return decimal_comma or "," not in cell


def _dialect(head: list[tuple[int, str, int]], last: tuple[int, str],
             name: str) -> tuple[str | None, bool]:
    """Delimiter (None: whitespace, "": one column) and decimal mark, read off the last line."""
    number, line = last
    for delimiter in ("\t", ";", ",", None):
        parts = _split(line, delimiter)
        decimal_comma = delimiter != "," and any("," in p for p in parts)
        numeric = [p for p in parts if p]
        if (len(parts) >= 2 or delimiter is None) and numeric and all(
                _is_number(p, decimal_comma) for p in numeric):
            return ("" if len(parts) == 1 else delimiter), decimal_comma
    if len(head) == 1 or not any(_NUMBER.match(c.strip()) for _n, text, _o in head
                                 for c in re.split(r"[,;\t ]", text)):
        raise WaveformError("samples", f"{name}: no data rows, no samples",
                            "header lines, then one row of numbers per sample")
    raise WaveformError("file", f"{name} line {number}: {line[:80]!r} is not a row of numbers",
                        "a table whose last line is numbers separated by commas, semicolons "
                        "or tabs")


def _number(cell: str, decimal_comma: bool) -> float:
    if cell in OVER_RANGE:
        return OVER_RANGE[cell]
    return float(cell.replace(",", ".") if decimal_comma else cell)


# --- layouts with a header row --------------------------------------------------------------------


def _data_start(cells: list[tuple[int, list[str]]], decimal_comma: bool, name: str) -> int:
    """Index in ``cells`` of the first data row (all cells numbers, none empty)."""
    for k, (_line, parts) in enumerate(cells[:_HEADER_LINES_MAX]):
        if parts and all(p and _is_number(p, decimal_comma) for p in parts):
            return k
    number, parts = cells[min(len(cells), _HEADER_LINES_MAX) - 1]
    raise WaveformError("file", f"{name}: no row of numbers in the first "
                        f"{_HEADER_LINES_MAX} lines (line {number}: {','.join(parts)[:80]!r})",
                        "header lines, then one row of numbers per sample")


def _matrix(rows: list[tuple[int, list[str]]], width: int, decimal_comma: bool,
            name: str) -> np.ndarray:
    """Rows of cells as floats; a short, long or non-numeric row is an error naming its line."""
    for number, parts in rows:
        if len(parts) != width:
            raise WaveformError("file", f"{name} line {number}: {len(parts)} values, the other "
                                f"rows have {width} (a file cut short, or a stray row)",
                                f"{width} values on every data row")
    try:
        return np.array([[_number(p, decimal_comma) for p in parts] for _n, parts in rows],
                        dtype=np.float64).reshape(len(rows), width)
    except ValueError:
        pass
    for number, parts in rows:  # find the line to name
        for j, p in enumerate(parts):
            if not _is_number(p, decimal_comma):
                raise WaveformError("samples", f"{name} line {number}, column {j + 1}: "
                                    f"non-numeric value {p!r}", "a number")
    raise WaveformError("file", f"{name}: the data rows cannot be read as numbers")


def _read_rows(block: str, number0: int, delimiter: str | None, decimal_comma: bool,
               name: str) -> tuple[np.ndarray, list[str]]:
    """The data block (from line ``number0`` on) as a float matrix, and some of the first
    column's texts (for their printed precision). Fast: pandas' C parser straight to floats;
    anything odd (a text cell, a short or long row, over-range marks) takes the slow path,
    which parses line by line and names the first bad line."""
    import pandas as pd

    last = block.rstrip().rsplit("\n", 1)[-1]
    # the row width from the middle of the block: a file cut short loses its last line, a
    # stray first row is one row; either is then named as the odd one
    middle = block.rfind("\n", 0, len(block) // 2) + 1
    end = block.find("\n", middle)
    width = len(_split(block[middle:end if end >= 0 else len(block)], delimiter))
    sep = r"\s+" if delimiter is None else ("\x1f" if delimiter == "" else delimiter)
    try:
        frame = pd.read_csv(io.StringIO(block), sep=sep, header=None, dtype=np.float64,
                            decimal="," if decimal_comma else ".", skipinitialspace=True,
                            quotechar='"', engine="python" if delimiter is None else "c")
        if frame.shape[1] > width and frame.iloc[:, width:].isna().all().all():
            frame = frame.iloc[:, :width]  # a trailing delimiter on every row (Rigol, Tek)
        data = frame.to_numpy(dtype=np.float64)
        if data.shape[1] != width or np.isnan(data).any():
            raise ValueError("missing or NaN cells")  # told apart on the slow path
    except (ValueError, TypeError, pd.errors.ParserError):
        rows = [(number0 + i, line) for i, line in enumerate(block.splitlines()) if line.strip()]
        split = [(n, _split(line, delimiter)) for n, line in rows]
        data = _matrix(split, width, decimal_comma, name)  # raises, naming the line
    sample = [*block[:20_000].splitlines()[:200], last]
    return data, [(_split(line, delimiter) or [""])[0] for line in sample if line.strip()]


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
    return _assemble(layout, header.labels, header.units_row, block.data, header.scope, meta,
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
    data, first_texts = _read_rows(text, number0, delimiter, decimal_comma, name)
    labels, units_row = _labels(lines, data.shape[1])
    header = Header(lines, labels, units_row, _key_values(lines))
    block = Block(data, first_texts, decimal_comma, name)
    layout = next(x for x in LAYOUTS if x.detect(header))
    table = layout.parse(header, block)
    if layout.name != "rigol":
        table.declared_rows = _declared_rows(lines, header.scope, name)
    return table


def _labels(header: list[tuple[int, list[str]]], width: int
            ) -> tuple[list[str] | None, list[str] | None]:
    """The column names and the units row (Keysight, PicoScope) above the data, if any."""
    if not header:
        return None, None
    last = header[-1][1]
    if len(header) >= 2 and len(header[-2][1]) >= width and len(last) >= width and (
            all(_unit_cell(u) for u in last[:width])):
        return header[-2][1], last
    if len(last) >= width:
        return last, None
    return None, None


def _unit_cell(text: str) -> bool:
    """A units-row cell: ``(ms)``, ``second``, ``Volt`` (Keysight, PicoScope)."""
    inner = text[1:-1] if text.startswith("(") and text.endswith(")") else text
    key = inner.strip().lower()
    return key in TIME_UNITS or key in VALUE_UNITS or key in ("", "sequence")


def _key_values(header: list[tuple[int, list[str]]]) -> dict[str, str]:
    """``Key,Value`` header lines (Tektronix, LeCroy) as a mapping."""
    out = {}
    for _number, parts in header:
        if len(parts) == 2 and parts[0] and not parts[0].startswith("#"):
            out[parts[0]] = parts[1]
    return out


def _split_label(label: str) -> tuple[str, str | None]:
    """``Time (s)`` -> ("Time", "s"), ``force_kN`` -> ("force", "kN"), ``CH1`` -> ("CH1", None)."""
    m = _LABEL_UNIT.match(label)
    if m and m.group(2):
        return m.group(1).strip(), m.group(2)
    if "_" in label:
        base, suffix = label.rsplit("_", 1)
        low = suffix.lower()
        if low in TIME_UNITS or low in VALUE_UNITS or base.lower() in QUANTITY_NAMES:
            return base, suffix
    return label, None


def _time_scale(unit: str, where: str) -> float:
    scale = TIME_UNITS.get(unit.strip().lower())
    if scale is None:
        raise WaveformError("units", f"{where}: unknown time unit {unit!r}",
                            "s, ms, us (µs), ns")
    return scale


def _value_unit(unit: str, where: str) -> tuple[str, float]:
    found = VALUE_UNITS.get(unit.strip().lower())
    if found is None:
        raise WaveformError("units", f"{where}: unknown units {unit!r}",
                            "V, mV, uV (µV), kV, N, kN, mN or lbf")
    return found


def _assemble(layout: str, labels: list[str] | None, units_row: list[str] | None,
              data: np.ndarray, scope: dict[str, str], meta: dict[str, Any],
              first_texts: list[str], decimal_comma: bool, name: str) -> Table:
    width = data.shape[1]
    names = labels[:width] if labels else [None] * width
    units = [(u[1:-1] if u.startswith("(") and u.endswith(")") else u) if u else None
             for u in (units_row[:width] if units_row else [None] * width)]
    split = [_split_label(n) if n is not None else (None, None) for n in names]
    time = None
    resolution = 0.0
    first_value = 0
    base0, unit0 = split[0]
    unit0 = unit0 or units[0]
    is_time = (base0 is not None and (base0.lower() in TIME_NAMES or (
        unit0 is not None and unit0.strip().lower() in TIME_UNITS)))
    if is_time and width >= 2:
        scale = _time_scale(unit0 or scope.get("Horizontal Units") or "s",
                            f"{name} column {names[0]!r}")
        time = data[:, 0] * scale
        resolution = scale * _resolution(first_texts, decimal_comma)
        first_value = 1
    elif is_time:
        raise WaveformError("channel", f"{name}: a time column but no sample column",
                            "a time column and at least one value column")
    elif labels is None and width >= 2 and _ramp(data[:, 0]):
        time, first_value = data[:, 0], 1  # header-less "time, values...": no shot is a ramp
        resolution = _resolution(first_texts, decimal_comma)
    vertical = scope.get("Vertical Units")
    columns = []
    for j in range(first_value, width):
        unit = split[j][1]
        unit = unit or units[j] or vertical
        where = f"{name} column {names[j]!r}" if names[j] else f"{name} column {j + 1}"
        if unit is not None:
            kind, factor = _value_unit(unit, where)
        elif layout in SCOPE_LAYOUTS:
            kind, factor = "V", 1.0
        else:
            kind, factor = None, 1.0
        values = data[:, j] * factor if factor != 1.0 else data[:, j]
        columns.append(Column(names[j] or f"column_{j + 1}", values, kind))
    if not columns:
        raise WaveformError("channel", f"{name}: no value column", "time, then value columns")
    _over_range(columns, name)
    return Table(layout, time, columns, meta, time_resolution=resolution)


def _over_range(columns: list[Column], name: str) -> None:
    for c in columns:
        bad = np.flatnonzero(np.isinf(c.values))
        if bad.size:
            raise WaveformError("samples", f"{name} column {c.label!r}: {bad.size} samples over "
                                f"range (first at sample {int(bad[0])}); the channel clipped",
                                "a record within the input range")


def _ramp(column: np.ndarray) -> bool:
    steps = np.diff(column)
    if steps.size < 1 or not np.isfinite(steps).all() or (steps <= 0).any():
        return False
    return float(np.ptp(steps)) <= 0.01 * float(np.mean(steps))


def _resolution(texts: list[str], decimal_comma: bool) -> float:
    """Half the value of the last printed digit of the coarsest number in ``texts``."""
    worst = 0.0
    for text in texts[:: max(1, len(texts) // 64)] + texts[-1:]:
        mantissa, _e, exponent = text.lower().partition("e")
        mantissa = mantissa.replace(",", ".") if decimal_comma else mantissa
        decimals = len(mantissa.partition(".")[2])
        worst = max(worst, 0.5 * 10.0 ** (int(exponent or 0) - decimals))
    return worst


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
        kind, factor = _value_unit(unit, f"{name} column {labels[j]!r}") if unit else ("V", 1.0)
        columns.append(Column(labels[j], data[:, j] * factor, kind))
    time = start + data[:, 0] * step
    _over_range(columns, name)
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
    data = _matrix(rows, 2 * len(blocks), decimal_comma, name)
    time = data[:, 0] * _time_scale(meta_all[0].get("Horizontal Units", "s"), name)
    columns = []
    for b, meta in enumerate(meta_all):
        label = meta.get("Source", f"CH{b + 1}")
        unit = meta.get("Vertical Units")
        kind, factor = _value_unit(unit, f"{name} {label}") if unit else ("V", 1.0)
        columns.append(Column(label, data[:, 2 * b + 1] * factor, kind))
    info: dict[str, Any] = {"layout": "tektronix-legacy"}
    if meta_all[0].get("Model Number"):
        info["instrument"] = f"Tektronix {meta_all[0]['Model Number']}"
    _over_range(columns, name)
    length = meta_all[0].get("Record Length")
    return Table("tektronix-legacy", time, columns, info,
                 time_resolution=_resolution([r[1][0] for r in rows], decimal_comma),
                 declared_rows=None if length is None else _count(length, "Record Length", name))


SIDE_BY_SIDE: tuple[tuple[str, Callable[[list[tuple[int, list[str]]]], bool],
                          Callable[[list[tuple[int, list[str]]], bool, str], Table]], ...] = (
    ("tektronix-legacy", _is_tek_legacy, _tek_legacy),
)
"""Layouts with the metadata beside the data, as (name, detect on the first lines' cells,
parse every line's cells): tried before :data:`LAYOUTS`."""


def _is_lecroy_segment(line: str) -> bool:
    """LeCroy's ``#1,<date>,0`` segment line is data of its header, not a comment."""
    return re.match(r"^#\d+[,;\t]", line) is not None
