"""What several commands share: option checks run as the command line is parsed, and the
model tables a command reads (``--table``, ``$SOLITONDE_TABLE``, the bundled ones, a set-up's)
with the plate material that picks one.

The table modules load only when a command asks for a table, so that ``solitonde --help`` and
commands without tables start fast."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from solitonde.instrument.inference.sizes import size_problem

if TYPE_CHECKING:
    from solitonde.instrument.inference.setups import Setup
    from solitonde.instrument.inference.table_set import TableChoiceError, TableSet


def sphere_sizes(value: Any) -> Any:
    """A ``--sphere-diameter`` or ``--diameter`` option's callback: each size in metres (one
    over 0.1 m is a size in mm, refused with the metres it means: exit 2)."""
    for v in value if isinstance(value, list | tuple) else [value]:
        problem = None if v is None else size_problem(v)
        if problem is not None:
            raise typer.BadParameter(problem)
    return value


def table_path(option: Path | None) -> Path:
    """``--table``, else ``$SOLITONDE_TABLE``, else the default table in data_samples/."""
    if option is not None:
        return option
    from solitonde.instrument.tables.bundled import default_table

    env = os.environ.get("SOLITONDE_TABLE")
    return Path(env) if env else default_table()


def table_set(options: Sequence[Path] | None) -> TableSet:
    """The tables ``--table`` names (files or folders, repeatable), else the default one.

    Raises TableError when one cannot be loaded (a command line names only tables it means)."""
    from solitonde.instrument.inference.table_set import TableSet
    from solitonde.instrument.tables.table import TableError

    paths = list(options or []) or [table_path(None)]
    tables = TableSet(paths, warm_up=False)
    if tables.problems:
        raise TableError("table", "; ".join(tables.problems))
    return tables


def setup_tables(setup: Setup, options: Sequence[Path] | None) -> TableSet:
    """The table a set-up names by id, looked for in this order: ``--table`` (files or
    folders), the bundled tables, ``$SOLITONDE_TABLE``. TableError when none has that id."""
    from solitonde.instrument.inference.table_set import TableSet
    from solitonde.instrument.tables.bundled import bundled_tables
    from solitonde.instrument.tables.table import TableError

    env = os.environ.get("SOLITONDE_TABLE")
    found: list[str] = []
    for paths in (list(options or []), bundled_tables(), [Path(env)] if env else []):
        if not paths:
            continue
        tables = TableSet(paths, warm_up=False)
        if setup.table in tables.by_id:
            return TableSet([tables.by_id[setup.table].path], warm_up=False)
        found += [tid for tid in tables.by_id if tid not in found]
    raise TableError("table", f"set-up {setup.id!r} names table {setup.table!r}, which is none "
                     f"of --table, the bundled tables and $SOLITONDE_TABLE (found: "
                     f"{', '.join(found) or 'none'})")


def choice_error(exc: TableChoiceError) -> str:
    """A table-choice error in the command line's words (the flag that picks the table)."""
    flag = "--plate-material" if exc.field == "plate_material" else "--table"
    return f"{flag}: {exc.message}"


def parse_material(text: str) -> Any:
    """``--plate-material``: a library name, or a JSON property mapping (checked here, so a bad
    key is named before anything runs). Raises ValueError naming the key."""
    from solitonde.model.materials import properties_from

    text = text.strip()
    if not text.startswith("{"):
        properties_from(text)
        return text
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not a library name nor a JSON mapping ({exc.msg} at character "
                         f"{exc.pos})") from None
    properties_from(value)
    return value
