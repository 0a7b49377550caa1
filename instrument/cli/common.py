"""What several commands' options share: checks run as the command line is parsed."""

from __future__ import annotations

from typing import Any

import typer

from solitonde.instrument.inference.sizes import size_problem


def sphere_sizes(value: Any) -> Any:
    """A ``--sphere-diameter`` or ``--diameter`` option's callback: each size in metres (one
    over 0.1 m is a size in mm, refused with the metres it means: exit 2)."""
    for v in value if isinstance(value, list | tuple) else [value]:
        problem = None if v is None else size_problem(v)
        if problem is not None:
            raise typer.BadParameter(problem)
    return value
