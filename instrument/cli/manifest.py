"""Campaign manifests: which file holds which plate, position and sphere size.

A lab's day of shots is a folder of scope or DAQ files whose names say little. A manifest, CSV or
YAML, gives one row per file or glob (relative to the manifest's folder)::

    file,plate_id,position,x_m,y_m,sphere_diameter_m,calibration_N_per_V
    p1_*.csv,P7,A1,0.100,0.020,0.00953,20.0

A YAML manifest is a list of such rows, or a mapping whose ``files`` list holds the rows and
whose other keys are defaults for every row. :func:`load` validates every row (a clear error
naming the row and the key) and :func:`match` resolves the rows to files: a row that matches no
file, or a file that two rows match, is an error naming the rows.
"""

from __future__ import annotations

import csv
import glob
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

from solitonde.instrument.errors import MessageError

KEYS = ("file", "plate_id", "position", "x_m", "y_m", "sphere_diameter_m",
        "calibration_N_per_V", "setup", "table", "plate_material")
"""The manifest's columns; ``file`` is required, the others optional. ``setup`` names an
instrument set-up by id, ``table`` a model table by id, ``plate_material`` a library material
or its properties as JSON."""
CHOICE_KEYS = ("setup", "table", "plate_material")
"""The columns that choose how a file is estimated (kept as its metadata, as text)."""
TEXT_LIMIT = 200
"""Longest plate_id or position (the service's limit)."""


class ManifestError(MessageError, ValueError):
    """A manifest that cannot be used; the message names the file, the row and the key."""

    subject = "--manifest"


class RowMetadata(TypedDict, total=False):
    """The metadata a manifest row gives its files: the waveform metadata keys of the location,
    and the columns that choose how a file is estimated (as text)."""

    plate_id: str
    position: str
    setup: str
    table: str
    plate_material: str
    x_m: float
    y_m: float
    sphere_diameter: float


@dataclass(frozen=True)
class Row:
    """One manifest row: where it is (``where``: file and row number), the file pattern, the
    metadata it gives its files (the waveform metadata keys ``plate_id``, ``position``,
    ``x_m``, ``y_m``, ``sphere_diameter``) and the calibration (N/V) for files in volts."""

    where: str
    pattern: str
    metadata: RowMetadata = field(default_factory=RowMetadata)
    calibration: float | None = None


def load(path: Path) -> list[Row]:
    """The rows of the manifest at ``path`` (``.csv`` or ``.yaml``/``.yml``), validated."""
    suffix = path.suffix.lower()
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ManifestError(f"--manifest: cannot read {str(path)!r} ({exc})") from None
    records: Sequence[tuple[str, Mapping[str, Any]]]
    if suffix == ".csv":
        records = _csv_records(text, path)
    elif suffix in (".yaml", ".yml"):
        records = _yaml_records(text, path)
    else:
        raise ManifestError(f"--manifest: {path.name} must end in .csv, .yaml or .yml")
    if not records:
        raise ManifestError(f"--manifest: {path.name} has no rows")
    return [_row(where, record) for where, record in records]


def _csv_records(text: str, path: Path) -> list[tuple[str, dict[str, str | None]]]:
    """Each row's cells as text (None where the row is short), named by the header."""
    lines = [line for line in text.splitlines() if line.strip() and not line.startswith("#")]
    if not lines:
        return []
    dialect = csv.Sniffer().sniff(lines[0], delimiters=",;\t") if any(
        d in lines[0] for d in ",;\t") else csv.excel
    reader = csv.DictReader(lines, dialect=dialect)
    _check_keys(reader.fieldnames or [], f"{path.name} header")
    out = []
    for i, record in enumerate(reader, start=2):
        if None in record:  # more cells than the header names
            raise ManifestError(f"--manifest: {path.name} row {i}: more values than the "
                                "header has columns")
        out.append((f"{path.name} row {i}", {k.strip(): (v.strip() if isinstance(v, str) else v)
                                             for k, v in record.items() if k is not None}))
    return out


def _yaml_records(text: str, path: Path) -> list[tuple[str, dict[str, Any]]]:
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ManifestError(f"--manifest: {path.name} is not valid YAML ({exc})") from None
    defaults: dict[str, Any] = {}
    if isinstance(doc, Mapping):
        defaults = {k: v for k, v in doc.items() if k != "files"}
        _check_keys(defaults, f"{path.name} (top level)")
        doc = doc.get("files")
    if not isinstance(doc, list):
        raise ManifestError(f"--manifest: {path.name} must hold a list of rows, or a mapping "
                            "with a 'files' list")
    out = []
    for i, item in enumerate(doc, start=1):
        if not isinstance(item, Mapping):
            raise ManifestError(f"--manifest: {path.name} entry {i} is not a mapping of "
                                f"{', '.join(KEYS)}")
        _check_keys(item, f"{path.name} entry {i}")
        out.append((f"{path.name} entry {i}", {**defaults, **item}))
    return out


def _check_keys(keys: Iterable[Any], where: str) -> None:
    unknown = [str(k) for k in keys if str(k).strip() not in KEYS]
    if unknown:
        raise ManifestError(f"--manifest: {where}: unknown column {unknown[0]!r} (allowed: "
                            f"{', '.join(KEYS)})")


def _blank(value: Any) -> bool:
    return value is None or (isinstance(value, str) and not value.strip())


def _text(record: Mapping[str, Any], where: str, key: str, limit: int) -> str | None:
    """A text column's value, stripped (None where blank), at most ``limit`` characters."""
    value = record.get(key)
    if _blank(value):
        return None
    text = str(value).strip()
    if len(text) > limit:
        raise ManifestError(f"--manifest: {where}: {key}: {len(text)} characters; at most "
                            f"{limit}")
    return text


def _row(where: str, record: Mapping[str, Any]) -> Row:
    pattern = record.get("file")
    if _blank(pattern):
        raise ManifestError(f"--manifest: {where}: file: missing (a file name or glob, "
                            "relative to the manifest's folder)")
    meta = RowMetadata()
    if (plate_id := _text(record, where, "plate_id", TEXT_LIMIT)) is not None:
        meta["plate_id"] = plate_id
    if (position := _text(record, where, "position", TEXT_LIMIT)) is not None:
        meta["position"] = position
    if (setup := _text(record, where, "setup", TEXT_LIMIT * 5)) is not None:
        meta["setup"] = setup
    if (table := _text(record, where, "table", TEXT_LIMIT * 5)) is not None:
        meta["table"] = table
    if (material := _text(record, where, "plate_material", TEXT_LIMIT * 5)) is not None:
        meta["plate_material"] = material
    if not _blank(record.get("x_m")):
        meta["x_m"] = _number(record["x_m"], where, "x_m")
    if not _blank(record.get("y_m")):
        meta["y_m"] = _number(record["y_m"], where, "y_m")
    if not _blank(record.get("sphere_diameter_m")):
        meta["sphere_diameter"] = _number(record["sphere_diameter_m"], where, "sphere_diameter_m")
    calibration = None
    if not _blank(record.get("calibration_N_per_V")):
        calibration = _number(record["calibration_N_per_V"], where, "calibration_N_per_V")
    return Row(where, str(pattern).strip(), meta, calibration)


_ALLOWED = {"x_m": ("a finite number of metres", lambda v: True),
            "y_m": ("a finite number of metres", lambda v: True),
            "sphere_diameter_m": ("a diameter in metres, 0 < D <= 1", lambda v: 0.0 < v <= 1.0),
            "calibration_N_per_V": ("a sensitivity in N/V > 0", lambda v: v > 0.0)}


def _number(value: Any, where: str, key: str) -> float:
    allowed, ok = _ALLOWED[key]
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ManifestError(f"--manifest: {where}: {key}: {value!r} is not a number (allowed: "
                            f"{allowed})") from None
    if not (math.isfinite(number) and ok(number)):
        raise ManifestError(f"--manifest: {where}: {key}: {value!r} is out of range (allowed: "
                            f"{allowed})")
    return number


def match(rows: list[Row], base: Path, extensions: Iterable[str] | None
          ) -> list[tuple[Path, Row]]:
    """Each manifest row's files, in row order; patterns are relative to ``base``.

    A glob keeps the regular files with one of ``extensions`` (None: every file whose name does
    not start with a dot); a plain name must exist. Raises :class:`ManifestError` for a row that
    matches nothing, or a file that two rows match.
    """
    wanted = None if extensions is None else {e.lower() for e in extensions}
    owner: dict[Path, Row] = {}
    out = []
    for row in rows:
        pattern = row.pattern if Path(row.pattern).is_absolute() else str(base / row.pattern)
        if glob.has_magic(row.pattern):
            found = sorted(Path(p) for p in glob.glob(pattern, recursive=True)
                           if Path(p).is_file() and not Path(p).name.startswith(".")
                           and (wanted is None or Path(p).suffix.lower() in wanted))
        else:
            found = [Path(pattern)] if Path(pattern).is_file() else []
        if not found:
            raise ManifestError(f"--manifest: {row.where}: no file matches {row.pattern!r} "
                                f"(looked in {str(base)!r})")
        for f in found:
            key = f.resolve()
            if key in owner:
                raise ManifestError(f"--manifest: {f.name} is matched by {owner[key].where} "
                                    f"and by {row.where}; give each file one row")
            owner[key] = row
            out.append((f, row))
    return out
