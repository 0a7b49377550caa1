"""Errors raised by the signal layer for waveforms and files it cannot accept.

Every one derives from :class:`SignalError`, which names the failing ``field``, says what is
wrong (``message``) and, where it helps, what is ``allowed``, and survives pickling whatever a
subclass's constructor takes (batch extraction may run in worker processes). The model and
instrument layers keep bases of their own with the same contract.
"""

from __future__ import annotations

from typing import Any


def _restore(cls: type[SignalError], args: tuple[Any, ...], state: dict[str, Any]
             ) -> SignalError:
    """Unpickle without calling the subclass's constructor (its signature is its own)."""
    exc = cls.__new__(cls, *args)
    exc.args = args
    exc.__dict__.update(state)
    return exc


class SignalError(Exception):
    """Base of the signal layer's errors.

    Attributes
    ----------
    field:
        The offending field or option, e.g. ``"samples"``, ``"time"``, ``"dt"``, ``"format"``,
        ``"channel"``.
    message:
        What is wrong, in plain language.
    allowed:
        Plain-language statement of what the field accepts, or ``None``.
    """

    def __init__(self, field: str, message: str, allowed: str | None = None) -> None:
        self.field = field
        self.message = message
        self.allowed = allowed
        super().__init__(f"{field}: {self.full_message}")

    @property
    def full_message(self) -> str:
        """The message with what is allowed, without the field."""
        return f"{self.message} (allowed: {self.allowed})" if self.allowed else self.message

    def __reduce__(self) -> tuple[Any, ...]:
        return _restore, (type(self), self.args, dict(self.__dict__))


class WaveformError(SignalError, ValueError):
    """Bad waveform input: names the failing field and, where it helps, what is allowed."""


class OptionNeeded(WaveformError):
    """The data need an option the caller did not give: ``sample_rate`` (no time axis) or
    ``calibration`` (samples in volts without one). ``option`` names it; ``field`` may carry a
    path prefix (``shots[2].calibration``)."""

    def __init__(self, option: str, message: str, allowed: str | None = None,
                 field: str | None = None) -> None:
        super().__init__(field or option, message, allowed)
        self.option = option
