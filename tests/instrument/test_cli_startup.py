"""The console script loads only what a call needs: the listing and --version import no command
module and none of the heavy libraries; a command imports its own module only, and `theory`
none of the heavy libraries either. The listing's
one-line helps are the commands' own, so the fast path cannot drift from the real one."""

from __future__ import annotations

import subprocess
import sys

import click
import typer

from solitonde.instrument.cli.main import COMMANDS, app_for, build_app

HEAVY = ("numba", "scipy", "pandas", "matplotlib", "h5py", "fastapi", "solitonde.signal.kernels")


def _loaded_after(*args: str) -> set[str]:
    code = ("import sys\nsys.argv = ['solitonde', *sys.argv[1:]]\n"
            "from solitonde.instrument.cli.main import main\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\n"
            f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
            "print(sorted(m for m in sys.modules\n"
            "             if m.startswith('solitonde.instrument.cli.cmd_')))")
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                         check=True).stdout.strip().splitlines()
    return set(eval(out[-2])) | set(eval(out[-1]))


def test_help_and_version_load_no_command_and_no_heavy_library():
    assert _loaded_after("--help") == set()
    assert _loaded_after("--version") == set()


def test_a_command_loads_its_own_module_only():
    loaded = _loaded_after("map", "--help")
    assert loaded == {"solitonde.instrument.cli.cmd_map"}, loaded


def test_theory_runs_without_numba_scipy_or_yaml():
    """`theory` reads e and tau_c from the shipped Chebyshev table: no integrator is loaded."""
    assert _loaded_after("theory") == {"solitonde.instrument.cli.cmd_theory"}
    assert _loaded_after("theory", "--grid") == {"solitonde.instrument.cli.cmd_theory"}


def test_the_listing_says_what_the_commands_say():
    full = typer.main.get_command(build_app())
    quick = typer.main.get_command(app_for(["--help"]))
    ctx = click.Context(full)
    assert full.list_commands(ctx) == quick.list_commands(ctx) == list(COMMANDS)
    for name in COMMANDS:
        real = full.get_command(ctx, name).get_short_help_str(limit=1000)
        listed = quick.get_command(ctx, name).get_short_help_str(limit=1000)
        assert real == listed, name


def test_an_unknown_command_still_gets_clicks_suggestion():
    result = subprocess.run([sys.executable, "-m", "solitonde.instrument.cli.main", "anlyze"],
                            capture_output=True, text=True)
    assert result.returncode == 2 and "analyze" in result.stderr, result.stderr
