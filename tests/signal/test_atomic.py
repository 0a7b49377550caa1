"""signal.atomic: a file is either whole or as it was (the one atomic-write helper)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from solitonde.signal.atomic import atomic_path, write_bytes, write_text


def test_a_written_file_is_whole_with_the_users_permissions(tmp_path: Path) -> None:
    target = tmp_path / "cal.json"
    write_text(target, '{"arr_factor": 0.9}\n')
    assert target.read_text() == '{"arr_factor": 0.9}\n'
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "queue.json"
    write_bytes(target, b"old")
    with pytest.raises(RuntimeError, match="disk"), atomic_path(target) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("disk full half-way")
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["queue.json"]


def test_a_durable_write_replaces_the_file(tmp_path: Path) -> None:
    target = tmp_path / "queue.json"
    write_text(target, "1")
    write_text(target, "2", durable=True)
    assert target.read_text() == "2"
    assert [p.name for p in tmp_path.iterdir()] == ["queue.json"]


def test_a_missing_folder_is_an_error_not_a_stray_file(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        write_text(tmp_path / "nope" / "x.json", "{}")
    assert list(tmp_path.iterdir()) == []
