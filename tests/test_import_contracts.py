"""The layers of docs/architecture.md hold, as import-linter's contracts.

The linter runs on the folders laid out as one package (``tests/support/package_tree.py``) with the
repository's configuration.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from package_tree import ROOT, package_tree


def test_the_import_contracts_hold(tmp_path: Path) -> None:
    linter = Path(sys.executable).with_name("lint-imports")
    if not linter.exists():
        pytest.skip("import-linter is not installed (pip install -e '.[dev]')")
    tree = package_tree(tmp_path)
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
    tree = package_tree(tmp_path)
    (tree / "solitonde" / "signal" / "leak.py").write_text(
        "from solitonde.model import errors\n")
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([str(linter), "--no-cache", str(ROOT / "pyproject.toml")], cwd=tree,
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode != 0
    assert "model and signal know nothing of each other BROKEN" in out.stdout
