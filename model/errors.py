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
        self.message = message
        self.allowed = allowed
        text = f"{field}: {message}"
        if allowed:
            text += f" (allowed: {allowed})"
        super().__init__(text)

    def __reduce__(self) -> tuple[type[SceneError], tuple[str, str, str | None]]:
        # The default rebuilds from args (the one formatted text) and fails on the three-argument
        # __init__: a SceneError could not cross a process boundary (process pool, Dask).
        return type(self), (self.field, self.message, self.allowed)


class SimulationError(RuntimeError):
    """A simulation that cannot be carried out as requested (e.g. a budget or stability limit)."""
