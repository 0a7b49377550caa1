"""Errors raised by the physics layer for input it cannot accept.

Every one derives from :class:`ModelError`, which names the failing ``field`` and says what is
wrong (``message``) and, where it helps, what is ``allowed``, and survives pickling whatever a
subclass's constructor takes (errors raised in a process pool or a Dask worker travel back to the
caller). The signal and instrument layers keep bases of their own with the same contract: the
layers import nothing from each other's errors.
"""

from __future__ import annotations

from typing import Any


def _restore(cls: type[ModelError], args: tuple[Any, ...], state: dict[str, Any]) -> ModelError:
    """Unpickle without calling the subclass's constructor (its signature is its own)."""
    exc = cls.__new__(cls, *args)
    exc.args = args
    exc.__dict__.update(state)
    return exc


class ModelError(Exception):
    """Base of the physics layer's errors.

    Attributes
    ----------
    field:
        Dotted path of the offending key, e.g. ``"plate.thickness"``.
    message:
        What is wrong, in plain language.
    allowed:
        Plain-language statement of what the field accepts, or ``None``.
    """

    field_in_text = True
    """``str()`` starts with ``field: ``; off where the message names its subject itself."""

    def __init__(self, field: str, message: str, allowed: str | None = None) -> None:
        self.field = field
        self.message = message
        self.allowed = allowed
        text = self.full_message
        super().__init__(f"{field}: {text}" if self.field_in_text else text)

    @property
    def full_message(self) -> str:
        """The message with what is allowed, without the field."""
        return f"{self.message} (allowed: {self.allowed})" if self.allowed else self.message

    def __reduce__(self) -> tuple[Any, ...]:
        return _restore, (type(self), self.args, dict(self.__dict__))


class SceneError(ModelError, ValueError):
    """Bad scene input: names the failing field (dotted path) and what is allowed."""


class SimulationError(ModelError, RuntimeError):
    """A simulation that cannot be carried out as requested (e.g. a budget or stability limit);
    the message says which (``step_budget_exceeded: ...``), the field is the scene's part."""

    field_in_text = False

    def __init__(self, message: str, field: str = "scene") -> None:
        super().__init__(field, message)
