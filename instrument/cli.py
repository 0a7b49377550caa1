"""The `solitonde` command line: one Typer app assembled from one module per command.

Each ``cmd_*.py`` module in this folder defines ``register(app)`` that adds its commands; list it
in ``COMMAND_MODULES`` to make it part of the CLI.
"""

from __future__ import annotations

import importlib

import typer

COMMAND_MODULES: list[str] = [
    "cmd_analyze",
    "cmd_samples",
    "cmd_simulate",
    "cmd_theory",
    "cmd_serve",
    "cmd_table",
    "cmd_invert",
    "cmd_map",
    "cmd_calibrate",
    "cmd_validate",
    "cmd_reproduce",
    "cmd_bench",
]

app = typer.Typer(
    name="solitonde",
    help="Plate NDE with highly nonlinear solitary waves: theory, simulation, analysis, service.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            typer.echo(f"solitonde {version('solitonde')}")
        except PackageNotFoundError:
            typer.echo("solitonde (not installed)")
        raise typer.Exit()


@app.callback()
def _root(
    _show_version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit."),
) -> None:
    """Plate NDE with highly nonlinear solitary waves: theory, simulation, analysis, service."""
    # A callback keeps `solitonde <command>` a group even while only one command is registered.


def build_app() -> typer.Typer:
    """Attach every command module's commands to the app (idempotent)."""
    if not getattr(app, "_solitonde_registered", False):
        for name in COMMAND_MODULES:
            importlib.import_module(f"solitonde.instrument.{name}").register(app)
        app._solitonde_registered = True  # type: ignore[attr-defined]
    return app


def main() -> None:
    """Console-script entry point."""
    build_app()()


if __name__ == "__main__":
    main()
