"""mypy passes on model/, signal/ and instrument/ with the configuration in pyproject.toml.

Run on the folders laid out as one package (``tests/support/package_tree.py``); about 10-30 s.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from package_tree import ROOT, package_tree


def _mypy(tree: Path, *packages: str) -> subprocess.CompletedProcess[str]:
    args = [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
            "--cache-dir", str(tree / ".mypy_cache")]
    for name in packages:
        args += ["-p", name]
    return subprocess.run(args, cwd=tree, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One tree and one mypy cache for the module (the second run is incremental)."""
    pytest.importorskip("mypy", reason="mypy is not installed (pip install -e '.[dev]')")
    return package_tree(tmp_path_factory.mktemp("types"))


def test_model_and_signal_type_check(tree: Path) -> None:
    out = _mypy(tree, "solitonde.model", "solitonde.signal")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Success: no issues found" in out.stdout


def test_instrument_type_check(tree: Path) -> None:
    """The application too: its CLI, service, inference, reports, tables and studies."""
    out = _mypy(tree, "solitonde.instrument")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Success: no issues found" in out.stdout


def test_a_type_error_is_caught(tree: Path) -> None:
    """The check can fail: a function that returns a string for a float."""
    wrong = tree / "solitonde" / "signal" / "wrong.py"
    wrong.write_text("def tof_s() -> float:\n    return 'late'\n")
    try:
        out = _mypy(tree, "solitonde.signal")
    finally:
        wrong.unlink()
    assert out.returncode != 0
    assert "wrong.py:2: error: Incompatible return value type" in out.stdout
