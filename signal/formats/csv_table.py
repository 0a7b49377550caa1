"""Reading a CSV-like text as a table: the delimiter and decimal mark, the data rows (pandas' C
parser, with a slow path that names the first bad line), the header's column names, units rows
and ``Key,Value`` lines, and the columns with every unit scaled to seconds, volts or newtons.

The writers' layouts that use these pieces, and the choice between them, are in
:mod:`.csv_layouts`.
"""

from __future__ import annotations

import io
import re
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
HEADER_LINES_MAX = 200
NUMBER_PATTERN = re.compile(r"^[+-]?(\d+([.,]\d*)?|[.,]\d+)([eE][+-]?\d+)?$")
LABEL_UNIT_PATTERN = re.compile(r"^(.*?)\s*[(\[]\s*([^)\]]*?)\s*[)\]]\s*$")


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


def count_of(text: str, key: str, name: str) -> int:
    try:
        return int(float(text))
    except ValueError:
        raise WaveformError("file", f"{name}: {key} {text!r} is not a number",
                            "a whole number of samples") from None


def check_length(table: Table, name: str) -> None:
    """A file with fewer rows than its header declares was cut short (a dropped link, a full
    disk): refused, since the shot's tail (often the reflection) is missing. A file cut exactly
    at a line end with no declared length cannot be told from a shorter record."""
    rows = len(table.columns[0].values) if table.columns else 0
    if table.declared_rows is not None and rows < table.declared_rows:
        raise WaveformError("file", f"{name}: {rows} data rows, its header declares "
                            f"{table.declared_rows}: the file is cut short (truncated)",
                            "the whole file as the instrument wrote it")


def split_cells(line: str, delimiter: str | None) -> list[str]:
    if delimiter == "":
        return [line.strip()]
    parts = line.split() if delimiter is None else line.split(delimiter)
    parts = [p.strip().strip('"').strip() for p in parts]
    while parts and parts[-1] == "":  # a trailing delimiter (Rigol, Tektronix legacy)
        parts.pop()
    return parts


def is_number(cell: str, decimal_comma: bool) -> bool:
    if cell in OVER_RANGE:
        return True
    if NUMBER_PATTERN.match(cell) is None:
        return cell.lower() in ("nan", "inf", "+inf", "-inf", "infinity", "-infinity")
    return decimal_comma or "," not in cell


def dialect(head: list[tuple[int, str, int]], last: tuple[int, str],
             name: str) -> tuple[str | None, bool]:
    """Delimiter (None: whitespace, "": one column) and decimal mark, read off the last line."""
    number, line = last
    for delimiter in ("\t", ";", ",", None):
        parts = split_cells(line, delimiter)
        decimal_comma = delimiter != "," and any("," in p for p in parts)
        numeric = [p for p in parts if p]
        if (len(parts) >= 2 or delimiter is None) and numeric and all(
                is_number(p, decimal_comma) for p in numeric):
            return ("" if len(parts) == 1 else delimiter), decimal_comma
    if len(head) == 1 or not any(NUMBER_PATTERN.match(c.strip()) for _n, text, _o in head
                                 for c in re.split(r"[,;\t ]", text)):
        raise WaveformError("samples", f"{name}: no data rows, no samples",
                            "header lines, then one row of numbers per sample")
    raise WaveformError("file", f"{name} line {number}: {line[:80]!r} is not a row of numbers",
                        "a table whose last line is numbers separated by commas, semicolons "
                        "or tabs")


def to_float(cell: str, decimal_comma: bool) -> float:
    if cell in OVER_RANGE:
        return OVER_RANGE[cell]
    return float(cell.replace(",", ".") if decimal_comma else cell)


def data_start(cells: list[tuple[int, list[str]]], decimal_comma: bool, name: str) -> int:
    """Index in ``cells`` of the first data row (all cells numbers, none empty)."""
    for k, (_line, parts) in enumerate(cells[:HEADER_LINES_MAX]):
        if parts and all(p and is_number(p, decimal_comma) for p in parts):
            return k
    number, parts = cells[min(len(cells), HEADER_LINES_MAX) - 1]
    raise WaveformError("file", f"{name}: no row of numbers in the first "
                        f"{HEADER_LINES_MAX} lines (line {number}: {','.join(parts)[:80]!r})",
                        "header lines, then one row of numbers per sample")


def matrix(rows: list[tuple[int, list[str]]], width: int, decimal_comma: bool,
            name: str) -> np.ndarray:
    """Rows of cells as floats; a short, long or non-numeric row is an error naming its line."""
    for number, parts in rows:
        if len(parts) != width:
            raise WaveformError("file", f"{name} line {number}: {len(parts)} values, the other "
                                f"rows have {width} (a file cut short, or a stray row)",
                                f"{width} values on every data row")
    try:
        return np.array([[to_float(p, decimal_comma) for p in parts] for _n, parts in rows],
                        dtype=np.float64).reshape(len(rows), width)
    except ValueError:
        pass
    for number, parts in rows:  # find the line to name
        for j, p in enumerate(parts):
            if not is_number(p, decimal_comma):
                raise WaveformError("samples", f"{name} line {number}, column {j + 1}: "
                                    f"non-numeric value {p!r}", "a number")
    raise WaveformError("file", f"{name}: the data rows cannot be read as numbers")


def read_rows(block: str, number0: int, delimiter: str | None, decimal_comma: bool,
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
    width = len(split_cells(block[middle:end if end >= 0 else len(block)], delimiter))
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
        split = [(n, split_cells(line, delimiter)) for n, line in rows]
        data = matrix(split, width, decimal_comma, name)  # raises, naming the line
    sample = [*block[:20_000].splitlines()[:200], last]
    return data, [(split_cells(line, delimiter) or [""])[0] for line in sample if line.strip()]


def labels_above(header: list[tuple[int, list[str]]], width: int
            ) -> tuple[list[str] | None, list[str] | None]:
    """The column names and the units row (Keysight, PicoScope) above the data, if any."""
    if not header:
        return None, None
    last = header[-1][1]
    if len(header) >= 2 and len(header[-2][1]) >= width and len(last) >= width and (
            all(unit_cell(u) for u in last[:width])):
        return header[-2][1], last
    if len(last) >= width:
        return last, None
    return None, None


def unit_cell(text: str) -> bool:
    """A units-row cell: ``(ms)``, ``second``, ``Volt`` (Keysight, PicoScope)."""
    inner = text[1:-1] if text.startswith("(") and text.endswith(")") else text
    key = inner.strip().lower()
    return key in TIME_UNITS or key in VALUE_UNITS or key in ("", "sequence")


def key_values(header: list[tuple[int, list[str]]]) -> dict[str, str]:
    """``Key,Value`` header lines (Tektronix, LeCroy) as a mapping."""
    out = {}
    for _number, parts in header:
        if len(parts) == 2 and parts[0] and not parts[0].startswith("#"):
            out[parts[0]] = parts[1]
    return out


def split_label(label: str) -> tuple[str, str | None]:
    """``Time (s)`` -> ("Time", "s"), ``force_kN`` -> ("force", "kN"), ``CH1`` -> ("CH1", None)."""
    m = LABEL_UNIT_PATTERN.match(label)
    if m and m.group(2):
        return m.group(1).strip(), m.group(2)
    if "_" in label:
        base, suffix = label.rsplit("_", 1)
        low = suffix.lower()
        if low in TIME_UNITS or low in VALUE_UNITS or base.lower() in QUANTITY_NAMES:
            return base, suffix
    return label, None


def time_scale(unit: str, where: str) -> float:
    scale = TIME_UNITS.get(unit.strip().lower())
    if scale is None:
        raise WaveformError("units", f"{where}: unknown time unit {unit!r}",
                            "s, ms, us (µs), ns")
    return scale


def value_unit(unit: str, where: str) -> tuple[str, float]:
    found = VALUE_UNITS.get(unit.strip().lower())
    if found is None:
        raise WaveformError("units", f"{where}: unknown units {unit!r}",
                            "V, mV, uV (µV), kV, N, kN, mN or lbf")
    return found


def assemble(layout: str, labels: list[str] | None, units_row: list[str] | None,
              data: np.ndarray, scope: dict[str, str], meta: dict[str, Any],
              first_texts: list[str], decimal_comma: bool, name: str) -> Table:
    width = data.shape[1]
    names = labels[:width] if labels else [None] * width
    units = [(u[1:-1] if u.startswith("(") and u.endswith(")") else u) if u else None
             for u in (units_row[:width] if units_row else [None] * width)]
    split = [split_label(n) if n is not None else (None, None) for n in names]
    time = None
    resolution = 0.0
    first_value = 0
    base0, unit0 = split[0]
    unit0 = unit0 or units[0]
    is_time = (base0 is not None and (base0.lower() in TIME_NAMES or (
        unit0 is not None and unit0.strip().lower() in TIME_UNITS)))
    if is_time and width >= 2:
        scale = time_scale(unit0 or scope.get("Horizontal Units") or "s",
                            f"{name} column {names[0]!r}")
        time = data[:, 0] * scale
        resolution = scale * printed_resolution(first_texts, decimal_comma)
        first_value = 1
    elif is_time:
        raise WaveformError("channel", f"{name}: a time column but no sample column",
                            "a time column and at least one value column")
    elif labels is None and width >= 2 and is_ramp(data[:, 0]):
        time, first_value = data[:, 0], 1  # header-less "time, values...": no shot is a ramp
        resolution = printed_resolution(first_texts, decimal_comma)
    vertical = scope.get("Vertical Units")
    columns = []
    for j in range(first_value, width):
        unit = split[j][1]
        unit = unit or units[j] or vertical
        where = f"{name} column {names[j]!r}" if names[j] else f"{name} column {j + 1}"
        if unit is not None:
            kind, factor = value_unit(unit, where)
        elif layout in SCOPE_LAYOUTS:
            kind, factor = "V", 1.0
        else:
            kind, factor = None, 1.0
        values = data[:, j] * factor if factor != 1.0 else data[:, j]
        columns.append(Column(names[j] or f"column_{j + 1}", values, kind))
    if not columns:
        raise WaveformError("channel", f"{name}: no value column", "time, then value columns")
    over_range(columns, name)
    return Table(layout, time, columns, meta, time_resolution=resolution)


def over_range(columns: list[Column], name: str) -> None:
    for c in columns:
        bad = np.flatnonzero(np.isinf(c.values))
        if bad.size:
            raise WaveformError("samples", f"{name} column {c.label!r}: {bad.size} samples over "
                                f"range (first at sample {int(bad[0])}); the channel clipped",
                                "a record within the input range")


def is_ramp(column: np.ndarray) -> bool:
    steps = np.diff(column)
    if steps.size < 1 or not np.isfinite(steps).all() or (steps <= 0).any():
        return False
    return float(np.ptp(steps)) <= 0.01 * float(np.mean(steps))


def printed_resolution(texts: list[str], decimal_comma: bool) -> float:
    """Half the value of the last printed digit of the coarsest number in ``texts``."""
    worst = 0.0
    for text in texts[:: max(1, len(texts) // 64)] + texts[-1:]:
        mantissa, _e, exponent = text.lower().partition("e")
        mantissa = mantissa.replace(",", ".") if decimal_comma else mantissa
        decimals = len(mantissa.partition(".")[2])
        worst = max(worst, 0.5 * 10.0 ** (int(exponent or 0) - decimals))
    return worst
