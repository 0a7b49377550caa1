"""``solitonde cache``: what the two caches hold, and clearing them.

``responses``: the plate responses table builds, layers, ``simulate`` and ``reproduce`` keep on
disk (:mod:`solitonde.instrument.tables.greens_cache`), so that a plate's response is computed
once. ``compiled``: numba's compiled kernels (:mod:`solitonde.model.jit_cache`), one folder per
version and source. Both are caches: clearing them costs time on the next run, never a result.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import TypedDict

import typer

from solitonde.instrument.cli.main import HELP_MARKUP

cache_app = typer.Typer(help="What the plate-response store and the compiled-code cache hold; "
                             "clear them.", no_args_is_help=True, rich_markup_mode=HELP_MARKUP)


class CompiledFolder(TypedDict):
    path: str
    bytes: int
    current: bool
    """The folder this version and source compile into."""


class ResponsesInfo(TypedDict):
    folder: str
    responses: int
    bytes: int
    max_bytes: int


class CacheInfo(TypedDict, total=False):
    responses: ResponsesInfo
    compiled: list[CompiledFolder]


def _which(responses: bool, compiled: bool) -> tuple[bool, bool]:
    """Neither option: both caches."""
    return (True, True) if not (responses or compiled) else (responses, compiled)


def _folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _compiled_folders() -> list[CompiledFolder]:
    from solitonde.model.jit_cache import PREFIX, cache_dir, default_root

    root, current = default_root(), cache_dir()
    if not root.is_dir():
        return []
    return [{"path": str(p), "bytes": _folder_bytes(p), "current": p == current}
            for p in sorted(root.iterdir()) if p.is_dir() and p.name.startswith(PREFIX)]


def _mb(n: float) -> str:
    return f"{n / 1e6:,.1f} MB"


@cache_app.command("info")
def info_cmd(
    responses: bool = typer.Option(False, "--responses", help="the plate-response store only"),
    compiled: bool = typer.Option(False, "--compiled", help="the compiled kernels only"),
    as_json: bool = typer.Option(False, "--json", help="print as JSON"),
) -> None:
    """Where each cache lives, how many entries and bytes it holds (both unless one is named)."""
    from solitonde.instrument.tables.greens_cache import DiskGreensCache

    show_responses, show_compiled = _which(responses, compiled)
    out: CacheInfo = {}
    if show_responses:
        store = DiskGreensCache().info()
        out["responses"] = {"folder": str(store.folder), "responses": store.responses,
                            "bytes": store.bytes, "max_bytes": store.max_bytes}
    if show_compiled:
        out["compiled"] = _compiled_folders()
    if as_json:
        typer.echo(json.dumps(out, indent=1))
        return
    if show_responses:
        typer.echo(f"responses: {store.responses} in {store.folder} ({_mb(store.bytes)} of "
                   f"{_mb(store.max_bytes)}; SOLITONDE_CACHE_MAX_MB sets the cap)")
    if show_compiled:
        folders = out["compiled"]
        typer.echo(f"compiled: {len(folders)} folder(s)" + ("" if folders else " (none yet)"))
        for f in folders:
            whose = "this source's" if f["current"] else "an earlier source's or version's"
            typer.echo(f"  {f['path']} ({_mb(f['bytes'])}): {whose}")


@cache_app.command("clear")
def clear_cmd(
    responses: bool = typer.Option(False, "--responses", help="the plate-response store only"),
    compiled: bool = typer.Option(False, "--compiled", help="the compiled kernels only (every "
                                  "version's; the next run compiles again)"),
) -> None:
    """Delete what a cache holds (both unless one is named). Only time is lost: the next table
    build computes its plate responses again, the next run compiles its kernels again."""
    from solitonde.instrument.tables.greens_cache import DiskGreensCache

    clear_responses, clear_compiled = _which(responses, compiled)
    if clear_responses:
        store = DiskGreensCache()
        typer.echo(f"responses: deleted {store.clear()} from {store.folder}")
    if clear_compiled:
        folders = _compiled_folders()
        for f in folders:
            shutil.rmtree(f["path"], ignore_errors=True)
        typer.echo(f"compiled: deleted {len(folders)} folder(s)")


def register(app: typer.Typer) -> None:
    """Add the `cache` group to the CLI."""
    app.add_typer(cache_app, name="cache")
