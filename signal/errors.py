"""Errors raised by the signal layer for waveforms and files it cannot accept."""

from __future__ import annotations


class WaveformError(ValueError):
    """Bad waveform input: names the failing field and, where it helps, what is allowed.

    Attributes
    ----------
    field:
        The offending field or option, e.g. ``"samples"``, ``"time"``, ``"dt"``, ``"format"``,
        ``"channel"``.
    allowed:
        Plain-language statement of what the field accepts, or ``None``.
    """

    def __init__(self, field: str, message: str, allowed: str | None = None) -> None:
        self.field = field
        self.message = message
        self.allowed = allowed
        text = f"{field}: {message}"
        if allowed:
            text += f" (allowed: {allowed})"
        super().__init__(text)
