"""The three folders laid out as one ``solitonde`` package under a temporary folder, for tools
that walk files rather than import them (import-linter, mypy): the editable install maps the
folders into ``solitonde`` through an import hook they cannot follow. Links to the files, plus
an ``__init__.py`` for ``solitonde`` and for ``signal`` (which has none on purpose)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LAYERS = ("model", "signal", "instrument")


def package_tree(into: Path) -> Path:
    """Build the tree under ``into``; returns ``into`` (put it on PYTHONPATH)."""
    package = into / "solitonde"
    for layer in LAYERS:
        for source in (ROOT / layer).rglob("*.py"):
            target = package / layer / source.relative_to(ROOT / layer)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.symlink_to(source)
    for init in (package / "__init__.py", package / "signal" / "__init__.py"):
        init.touch()
    return into
