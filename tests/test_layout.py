"""Repository layout: the mapped folders, the stdlib `signal` (the one-way dependencies are
import-linter contracts: tests/test_import_contracts.py)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_signal_folder_is_not_a_regular_package():
    assert (ROOT / "signal").is_dir()
    assert not (ROOT / "signal" / "__init__.py").exists()


def test_stdlib_signal_wins_from_the_repository_root():
    """`python -c "import signal; signal.SIGINT"` from the root must reach the stdlib module."""
    out = subprocess.run(
        [sys.executable, "-c", "import signal; signal.SIGINT; print(signal.__file__)"],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert not Path(out.stdout.strip()).resolve().is_relative_to(ROOT)


def test_package_imports_from_the_root_and_elsewhere(tmp_path):
    code = ("import asyncio, subprocess, signal; signal.SIGINT; "
            "import solitonde.model, solitonde.instrument, solitonde.signal; "
            "print(solitonde.model.__file__)")
    for cwd in (ROOT, tmp_path):
        out = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True,
                             text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        assert Path(out.stdout.strip()).resolve().is_relative_to(ROOT / "model")


def test_every_instrument_sub_package_says_what_lives_there():
    """The layers themselves are import-linter contracts (tests/test_import_contracts.py)."""
    for init in sorted((ROOT / "instrument").glob("*/__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text()))
        assert doc and len(doc) > 80, init.parent.name


def test_ruff_is_clean():
    """The lint configuration in pyproject.toml holds for the whole tree."""
    ruff = Path(sys.executable).with_name("ruff")
    out = subprocess.run([str(ruff), "check", "--output-format", "concise", str(ROOT)],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
