"""The layers of DESIGN.md hold: import-linter's contracts in pyproject.toml (``lint-imports``).

The editable install maps the three folders into ``solitonde`` through an import hook, which the
linter cannot walk; the test lays them out as one package under a temporary folder (links to the
files, and an ``__init__.py`` for ``solitonde`` and for ``signal``, which has none on purpose) and
runs ``lint-imports`` there on the repository's configuration.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("model", "signal", "instrument")


def _package_tree(into: Path) -> Path:
    package = into / "solitonde"
    for layer in LAYERS:
        for source in (ROOT / layer).rglob("*.py"):
            target = package / layer / source.relative_to(ROOT / layer)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.symlink_to(source)
    for init in (package / "__init__.py", package / "signal" / "__init__.py"):
        init.touch()
    return into


def test_the_import_contracts_hold(tmp_path: Path) -> None:
    linter = Path(sys.executable).with_name("lint-imports")
    if not linter.exists():
        pytest.skip("import-linter is not installed (pip install -e '.[dev]')")
    tree = _package_tree(tmp_path)
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([str(linter), "--no-cache", str(ROOT / "pyproject.toml")], cwd=tree,
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "BROKEN" not in out.stdout
    assert "5 kept, 0 broken" in out.stdout, out.stdout


def test_a_broken_contract_is_caught(tmp_path: Path) -> None:
    """The check can fail: a signal module that imports the model breaks two contracts."""
    linter = Path(sys.executable).with_name("lint-imports")
    if not linter.exists():
        pytest.skip("import-linter is not installed (pip install -e '.[dev]')")
    tree = _package_tree(tmp_path)
    (tree / "solitonde" / "signal" / "leak.py").write_text(
        "from solitonde.model import errors\n")
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([str(linter), "--no-cache", str(ROOT / "pyproject.toml")], cwd=tree,
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode != 0
    assert "model and signal know nothing of each other BROKEN" in out.stdout
