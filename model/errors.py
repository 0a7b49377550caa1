"""Errors raised by the physics layer for input it cannot accept."""

from __future__ import annotations


class SceneError(ValueError):
    """Bad scene input: names the failing field (dotted path) and what is allowed.

    Attributes
    ----------
    field:
        Dotted path of the offending key, e.g. ``"plate.thickness"``.
    allowed:
        Plain-language statement of what the field accepts.
    """

    def __init__(self, field: str, message: str, allowed: str | None = None) -> None:
        self.field = field
        self.allowed = allowed
        text = f"{field}: {message}"
        if allowed:
            text += f" (allowed: {allowed})"
        super().__init__(text)


class SimulationError(RuntimeError):
    """A simulation that cannot be carried out as requested (e.g. a budget or stability limit)."""
