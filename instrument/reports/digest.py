"""What an inspection report vouches for, as one SHA-256 a reviewer can check later.

The digest covers the stored data the report shows, never the time it was rendered: per
measurement its id, its position, each shot's sample hash (the SHA-256 the store keeps of the
samples) and its stored result with the provenance (software version, extractor, table and its
SHA-256, set-up revision, chain calibration). Each measurement's entry is serialised as
canonical JSON (RFC 8785: sorted keys, shortest round-trip numbers, no whitespace) and hashed;
the report's digest is the hash of the canonical JSON list of the entries, in id order. The same
stored data give the same digest on any machine and version; a measurement added, reanalysed or
deleted gives another, and :func:`changes` says which.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, TypedDict

import rfc8785


class DigestItem(TypedDict):
    """One measurement's part of the digest: its id, position, shots' sample hashes and its
    stored result (passed through as the store keeps it)."""

    id: int
    position: str | None
    shots_sha256: list[str]
    result: dict[str, Any]


ALGORITHM = "sha256 of RFC 8785 canonical JSON"
"""How the digest is made, printed beside it."""


def canonical(value: Any) -> bytes:
    """``value`` as RFC 8785 canonical JSON."""
    return rfc8785.dumps(value)


def entry(measurement_id: Any, position: Any, shot_sha256: Sequence[str],
          result: Mapping[str, Any]) -> DigestItem:
    """One measurement's part of the digest: what identifies it and what it answered."""
    return {"id": measurement_id, "position": position, "shots_sha256": list(shot_sha256),
            "result": dict(result)}


def entry_digest(item: Mapping[str, Any]) -> str:
    """The SHA-256 of one entry's canonical JSON."""
    return hashlib.sha256(canonical(dict(item))).hexdigest()


def data_digest(entries: Iterable[Mapping[str, Any]]) -> str:
    """The report's digest: the SHA-256 of its entries' canonical JSON, in id order."""
    ordered = sorted((dict(e) for e in entries), key=lambda e: str(e["id"]).zfill(20))
    return hashlib.sha256(canonical(ordered)).hexdigest()


def changes(reported: Sequence[Mapping[str, Any]],
            current: Sequence[Mapping[str, Any]]) -> list[str]:
    """What differs between the entries a report holds and those the store holds now, one line
    each: a measurement added, deleted, reanalysed (its result changed) or whose samples changed.
    Empty when they are the same."""
    before = {str(e["id"]): e for e in reported}
    now = {str(e["id"]): e for e in current}
    out = []
    for key in sorted(set(before) | set(now), key=lambda k: k.zfill(20)):
        old, new = before.get(key), now.get(key)
        if old is None:
            assert new is not None
            out.append(f"measurement {key} added since (position {new['position']!r})")
        elif new is None:
            out.append(f"measurement {key} deleted since (position {old['position']!r})")
        elif old["shots_sha256"] != new["shots_sha256"]:
            out.append(f"measurement {key}: its shots' samples differ")
        elif entry_digest(old) != entry_digest(new):
            what = "reanalysed since" if old["result"] != new["result"] else "changed"
            out.append(f"measurement {key} {what} (position {new['position']!r})")
    return out
