"""Options mean the same everywhere: `--scene` on every command that takes a scene (simulate's
positional file kept as an alias), `--set KEY=null` restoring a key's default, and help text
with conventional value labels (no raw ``<bool>`` or ``<list[str]>``)."""

from __future__ import annotations

import json
import re
from pathlib import Path

from typer.testing import CliRunner

from solitonde.instrument.cli.main import build_app
from solitonde.model.scene import load_scene

SCENE = Path(__file__).resolve().parents[2] / "data_samples" / "scenes" / "steel_plate.yaml"
FAST = ["--set", "effects.plate_model=infinite"]


def _run(*args: str):
    return CliRunner().invoke(build_app(), [str(a) for a in args])


def test_simulate_takes_the_scene_as_an_option_and_as_before_as_an_argument():
    by_option = _run("simulate", "--scene", SCENE, *FAST, "--json")
    by_argument = _run("simulate", SCENE, *FAST, "--json")
    assert by_option.exit_code == by_argument.exit_code == 0, by_option.output
    a, b = json.loads(by_option.stdout), json.loads(by_argument.stdout)
    assert (a["tof_s"], a["arr"]) == (b["tof_s"], b["arr"])
    other = SCENE.with_name("elsewhere.yaml")
    clash = _run("simulate", SCENE, "--scene", other, "--json")
    assert clash.exit_code == 2 and "--scene" in clash.output


def test_set_null_clears_a_key_so_its_default_applies(tmp_path):
    scene = tmp_path / "fast.yaml"
    scene.write_text("striker: {velocity: 0.5}\nplate: {thickness: 4.0e-3}\n")
    assert load_scene(scene).striker.velocity == 0.5
    cleared = load_scene(scene, ["striker.velocity=null"])
    assert cleared.striker.velocity is None and cleared.striker.drop_height == 5e-3
    assert cleared.plate.thickness == 4.0e-3  # the rest of the file stands
    assert load_scene(scene, ["plate.thickness=null"]).plate.thickness == 3.18e-3


def test_theory_and_table_build_take_scene_too():
    for command in (("theory",), ("table", "build")):
        text = _run(*command, "--help").output
        assert re.search(r"--scene\b", text), (command, text)


def test_help_shows_conventional_labels():
    for command in (("serve",), ("analyze",), ("simulate",), ("table", "build"), ("invert",)):
        text = _run(*command, "--help").output
        assert not re.search(r"<(bool|str|int|float|path|list\[[^]]*\]|int range)>", text), (
            command, text)
    serve = _run("serve", "--help").output
    assert re.search(r"--port INTEGER", serve) and re.search(r"--insecure\s+serve", serve)


def test_a_wide_table_leaves_out_columns_instead_of_cutting_numbers():
    import io

    from rich.console import Console

    from solitonde.instrument.cli.console_tables import Column, fitted_table

    columns = [Column("source", text=True), Column("TOF (us)"), Column("ARR"),
               Column("t_inc (us)", drop_order=2), Column("F_inc (N)", drop_order=1)]
    rows = [["synthetic_D19.05_t4.83_snr30.tdms", "1270.5", "0.1203", "272.09", "134.6"]] * 3
    for width, kept in ((80, 5), (50, 3), (20, 3)):
        out = io.StringIO()
        console = Console(file=out, width=width, color_system=None)
        table, note = fitted_table(console, "Shots", columns, rows)
        console.print(table)
        text = out.getvalue()
        assert "…" not in text, text
        assert len(table.columns) == kept, (width, text)
        assert "1270.5" in text.replace("\n", "") or width == 20
        assert (note is None) == (kept == 5)
        if note:
            assert "t_inc (us)" in note and "--json" in note
