"""Commands that write into a folder refuse a file given as that folder before doing the work
(a traceback after minutes of `bench accuracy` runs, or from `samples`, before)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app


@pytest.mark.parametrize("command", [["samples"], ["bench", "accuracy", "--quick"]])
def test_out_a_file_is_a_usage_error(tmp_path: Path, command: list[str]) -> None:
    target = tmp_path / "afile"
    target.write_text("keep me")
    res = CliRunner().invoke(build_app(), [*command, "--out", str(target)])
    assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.output
    assert "error: --out: " in res.output and "give a folder" in res.output
    assert target.read_text() == "keep me"
