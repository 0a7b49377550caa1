"""The base of the instrument layer's errors.

Every error the instrument raises for input it cannot use derives from :class:`InstrumentError`:
it names the failing ``field``, says what is wrong (``message``) and, where it helps, what is
``allowed``, and survives pickling whatever a subclass's constructor takes (a table build or a
validation runs its points in worker processes or on Dask, and an error raised there travels
back). The model and signal layers keep bases of their own with the same contract.
"""

from __future__ import annotations

from typing import Any


def _restore(cls: type[InstrumentError], args: tuple[Any, ...], state: dict[str, Any]
             ) -> InstrumentError:
    """Unpickle without calling the subclass's constructor (its signature is its own)."""
    exc = cls.__new__(cls, *args)
    exc.args = args
    exc.__dict__.update(state)
    return exc


class InstrumentError(Exception):
    """Base of the instrument layer's errors.

    Attributes
    ----------
    field:
        What is wrong: a flag, a metadata key, a table, a setting, ``"store"``.
    message:
        What is wrong with it, in plain language.
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


class MessageError(InstrumentError):
    """An instrument error whose message names its own subject (a file and row, a store path):
    raised with the message alone, its ``field`` a fixed name per class (:attr:`subject`)."""

    field_in_text = False
    subject = "input"

    def __init__(self, message: str) -> None:
        super().__init__(self.subject, message)
