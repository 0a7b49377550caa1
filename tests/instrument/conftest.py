"""Fixtures of the instrument's tests: the service run in-process on a store in a temporary
folder."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings


@pytest.fixture
def service_client(tmp_path: Path) -> Iterator[Callable[..., TestClient]]:
    """Make a started TestClient of the service: its store in ``tmp_path``, the keyword arguments
    as :class:`Settings` fields (no table unless ``table_path`` is given). Each client made is
    shut down (lifespan and store closed) after the test."""
    with contextlib.ExitStack() as stack:

        def make(**fields: Any) -> TestClient:
            fields.setdefault("store_path", tmp_path / "store.sqlite")
            return stack.enter_context(TestClient(build_app(Settings(**fields))))

        yield make


@pytest.fixture
def client(service_client: Callable[..., TestClient]) -> TestClient:
    """The service with its default settings and no table."""
    return service_client()
