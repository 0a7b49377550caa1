"""The measurement store's errors: each names its subject (the store, a set-up, a key) and
says what was kept."""

from __future__ import annotations

from solitonde.instrument.errors import MessageError


class StoreError(MessageError, RuntimeError):
    """The store cannot be opened, or a stored record fails its integrity check."""

    subject = "store"


class StoreFull(StoreError):
    """The store's disk (or the process's file-size limit) has no room for a write; nothing of
    that write was kept, reads go on, and writes succeed again once there is room."""


class SchemaTooOld(StoreError):
    """A store of an earlier schema: ``solitonde store migrate`` brings it up."""


class SetupGone(StoreError):
    """A measurement names a set-up revision the store no longer holds (deleted meanwhile):
    nothing was written."""

    subject = "setup"


class SetupConflict(StoreError):
    """A change based on a set-up revision that is no longer the newest (another change came
    first), or a result of an older revision over a newer one: nothing was written."""

    subject = "setup"


class KeyTaken(MessageError, RuntimeError):
    """An ``Idempotency-Key`` another request stored first (a concurrent retry): nothing was
    written; the caller answers with that request's measurement. The message is the key."""

    subject = "Idempotency-Key"
