"""`solitonde table build` on the command line: Ctrl-C says where the work is kept and how to
resume (exit 130), instead of a traceback with exit 1."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from solitonde.instrument.cli import cmd_table
from solitonde.instrument.cli.main import build_app

GRID = ["--diameters", "4.76e-3", "--thicknesses", "3e-3", "--distances", "0.3", "--workers",
        "1", "--no-progress"]


def _interrupting(inside_numba: bool):
    def build_table(sweep, out, **kw):
        Path(str(out) + ".partial").write_bytes(b"")  # what an interrupted build leaves
        if not inside_numba:
            raise KeyboardInterrupt
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:  # how numba re-raises Ctrl-C from compiled code
            raise SystemError("CPUDispatcher returned a result with an exception set") from exc
    return build_table


@pytest.mark.parametrize("inside_numba", [False, True])
def test_ctrl_c_names_the_partial_file_and_exits_130(tmp_path: Path, monkeypatch,
                                                     inside_numba: bool) -> None:
    monkeypatch.setattr(cmd_table, "build_table", _interrupting(inside_numba))
    out = tmp_path / "t.h5"
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out", str(out)])
    assert res.exit_code == 130 and isinstance(res.exception, SystemExit), res.output
    assert "interrupted" in res.output and "t.h5.partial" in res.output
    assert "resume" in res.output


def test_other_system_errors_are_not_taken_for_ctrl_c(tmp_path: Path, monkeypatch) -> None:
    def broken(sweep, out, **kw):
        raise SystemError("something else")
    monkeypatch.setattr(cmd_table, "build_table", broken)
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out",
                                           str(tmp_path / "t.h5")])
    assert isinstance(res.exception, SystemError)


def test_an_existing_table_is_not_replaced_without_overwrite(tmp_path: Path, monkeypatch) -> None:
    """`table build` onto an existing file (without --out: the bundled table) is refused before
    any work, naming --overwrite; with --overwrite it builds; a partial file is a resume."""
    calls: list[Path] = []

    def build_table(sweep, out, **kw):
        calls.append(out)
        raise cmd_table.TableError("stop here")  # the build itself is not under test

    monkeypatch.setattr(cmd_table, "build_table", build_table)
    out = tmp_path / "t.h5"
    out.write_bytes(b"a finished table")
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out", str(out)])
    assert res.exit_code == 2 and "--overwrite" in res.output and calls == []
    assert out.read_bytes() == b"a finished table"
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID])
    assert res.exit_code == 2 and "the bundled table" in res.output and calls == []
    res = CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out", str(out),
                                           "--overwrite"])
    assert calls == [out]
    Path(str(out) + ".partial").write_bytes(b"")  # an interrupted rebuild resumes
    CliRunner().invoke(build_app(), ["table", "build", *GRID, "--out", str(out)])
    assert calls == [out, out]
