"""``solitonde store``: keep the measurement store as a record of inspections.

``backup`` (SQLite's online backup, safe while the server writes), ``check`` (integrity, schema
version, every trace's SHA-256; exit 1 when not ok), ``migrate`` (to this version's schema, after
a backup) and ``reanalyze`` (recompute features and estimates with the current version and
tables, keeping the earlier results).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from solitonde.instrument.cli.main import HELP_MARKUP

if TYPE_CHECKING:
    from solitonde.instrument.service.reanalysis import Brief, Recomputed

store_app = typer.Typer(help="Back up, check, migrate and reanalyze a measurement store.",
                        no_args_is_help=True, rich_markup_mode=HELP_MARKUP)


def _fail(message: str, code: int = 2) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


@store_app.command("backup")
def backup_cmd(
    store: Path = typer.Argument(..., help="the store (SQLite file)"),
    dest: Path = typer.Argument(..., help="the backup file to write (must not exist)"),
    as_json: bool = typer.Option(False, "--json", help="print the report as JSON"),
) -> None:
    """Copy the store with SQLite's online backup: one consistent state, safe while the server
    writes; the copy is checked, then renamed into place."""
    from solitonde.instrument.service.store import StoreError
    from solitonde.instrument.service.store_admin import backup

    try:
        report = backup(store, dest)
    except StoreError as exc:
        _fail(str(exc))
    if as_json:
        typer.echo(json.dumps(report))
        return
    typer.echo(f"backed up {report['store']} to {report['backup']}: "
               f"{report.get('measurements', 0)} measurements, {report.get('shots', 0)} shots, "
               f"schema {report['schema_version']}, {report['bytes']:,} bytes in "
               f"{report['seconds']:.2f} s (integrity ok)")


@store_app.command("check")
def check_cmd(
    store: Path = typer.Argument(..., help="the store (SQLite file)"),
    traces: bool = typer.Option(True, "--traces/--no-traces",
                                help="decode every trace and verify its SHA-256"),
    as_json: bool = typer.Option(False, "--json", help="print the report as JSON"),
) -> None:
    """Integrity, foreign keys, schema version and every trace's checksum; exit 1 when not ok."""
    from solitonde.instrument.service.store import StoreError
    from solitonde.instrument.service.store_admin import check

    try:
        report = check(store, traces=traces)
    except StoreError as exc:
        _fail(str(exc))
    if as_json:
        typer.echo(json.dumps(report))
    else:
        typer.echo(f"{report['store']}: {'ok' if report['ok'] else 'NOT OK'}  schema "
                   f"{report['schema_version']} (current {report['schema_current']}), integrity "
                   f"{report['integrity'] if report['integrity'] == 'ok' else 'FAILED'}, "
                   f"{report.get('measurements', 0)} measurements, {report.get('shots', 0)} "
                   f"shots, {report.get('earlier_results', 0)} earlier results, "
                   f"{report['traces_checked']} traces checked")
        for problem in report["problems"]:
            typer.echo(f"  - {problem}")
    if not report["ok"]:
        raise typer.Exit(1)


@store_app.command("migrate")
def migrate_cmd(
    store: Path = typer.Argument(..., help="the store (SQLite file)"),
    backup_to: Path | None = typer.Option(None, "--backup-to", help="where the backup taken "
                                          "first goes (default: beside the store)"),
    as_json: bool = typer.Option(False, "--json", help="print the report as JSON"),
) -> None:
    """Bring the store to this version's schema: a backup first, then every step in one
    transaction (all or nothing). A current store is left alone."""
    from solitonde.instrument.service.store import StoreError
    from solitonde.instrument.service.store_admin import migrate

    try:
        report = migrate(store, backup_to)
    except StoreError as exc:
        _fail(str(exc))
    if as_json:
        typer.echo(json.dumps(report))
    elif report["from"] == report["to"]:
        typer.echo(f"{report['store']}: schema {report['to']} already current; nothing to do")
    else:
        typer.echo(f"{report['store']}: schema {report['from']} -> {report['to']} (backup: "
                   f"{report['backup']})")


def _mm(v: Any) -> str:
    return "-" if v is None else f"{1e3 * float(v):.3f}"


def _table(b: Brief) -> str:
    if b["table"] is None:
        return "none"
    sha256 = b["table_sha256"]
    return f"{b['table']}@{sha256[:8]}" if sha256 else b["table"]


@store_app.command("reanalyze")
def reanalyze_cmd(
    store: Path = typer.Argument(..., help="the store (SQLite file)"),
    table: list[Path] = typer.Option([], "--table", help="model table or folder, repeatable "
                                     "(default: $SOLITONDE_TABLE, else the bundled table)"),
    plate_id: str | None = typer.Option(None, "--plate-id", help="only this plate's "
                                        "measurements"),
    as_json: bool = typer.Option(False, "--json", help="print the report as JSON"),
) -> None:
    """Recompute features and estimates of stored measurements with this version and these
    tables; each earlier result is kept beside the new one (the API serves the newest)."""
    from solitonde.instrument.cli.common import table_set
    from solitonde.instrument.service.reanalysis import reanalyze
    from solitonde.instrument.service.store import Store, StoreError
    from solitonde.instrument.tables.table import TableError

    if not store.is_file():
        _fail(f"no store at {str(store)!r}")
    try:
        tables = table_set(table)
    except TableError as exc:
        _fail(f"--table: {exc}")
    try:
        opened = Store(store, background_checkpoint=False)
    except StoreError as exc:
        _fail(f"store: {exc}")

    def show(line: Recomputed) -> None:
        if as_json:
            return
        b, a = line["before"], line["after"]
        typer.echo(f"{line['id']:>6}  {line['plate_id'] or '-'}/{line['position'] or '-'}  "
                   f"table {_table(b)} -> {_table(a)}  thickness {_mm(b['thickness_m'])} -> "
                   f"{_mm(a['thickness_m'])} mm  version {b['software_version'] or '?'} -> "
                   f"{a['software_version']}  ({line['earlier_results']} earlier kept)")

    try:
        report = reanalyze(opened, tables, plate_id=plate_id, progress=show)
    except StoreError as exc:
        _fail(f"store: {exc}")
    finally:
        opened.close()
    if as_json:
        typer.echo(json.dumps(report))
    else:
        for f in report["failed"]:
            typer.echo(f"{f['id']:>6}  not reanalyzed: {f['reason']}")
        typer.echo(f"reanalyzed {len(report['reanalyzed'])} measurements, "
                   f"{len(report['failed'])} kept as they were")
    if report["failed"]:
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Add the `store` group to the CLI."""
    app.add_typer(store_app, name="store")
