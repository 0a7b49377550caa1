"""`solitonde bench accuracy [--json]`: what each plate model and resolution costs and buys."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add the `bench` command group."""
    group = typer.Typer(help="Benchmarks of the model.", no_args_is_help=True)
    app.add_typer(group, name="bench")
