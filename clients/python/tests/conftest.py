"""Fixtures of the client's unit tests: a scripted fake of the service behind
``httpx.MockTransport`` (``attune_client_fakes``), and clients that record their backoff
sleeps instead of sleeping."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from attune_client import AsyncClient, Client
from attune_client_fakes import BASE_URL, KEY, FakeService, MakeAsyncClient, MakeClient


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture
def service() -> FakeService:
    return FakeService()


@pytest.fixture
def sleeps() -> list[float]:
    """The delays the clients made by the fixtures waited (they do not really sleep)."""
    return []


@pytest.fixture
def make_client(service: FakeService, sleeps: list[float]) -> Iterator[MakeClient]:
    """``make_client(handler=None, **kwargs)``: a ``Client`` on a ``MockTransport``."""
    made: list[Client] = []

    def make(
        handler: Callable[[httpx.Request], httpx.Response] | None = None, **kwargs: Any
    ) -> Client:
        transport = httpx.MockTransport(handler or service.handler)
        client = Client(BASE_URL, KEY, transport=transport, **kwargs)
        client._sleep = sleeps.append
        made.append(client)
        return client

    yield make
    for client in made:
        client.close()


@pytest.fixture
async def make_async_client(
    service: FakeService, sleeps: list[float]
) -> AsyncIterator[MakeAsyncClient]:
    """``make_async_client(handler=None, **kwargs)``: an ``AsyncClient`` on a
    ``MockTransport``."""
    made: list[AsyncClient] = []

    def make(
        handler: Callable[[httpx.Request], httpx.Response] | None = None, **kwargs: Any
    ) -> AsyncClient:
        transport = httpx.MockTransport(handler or service.handler)
        client = AsyncClient(BASE_URL, KEY, transport=transport, **kwargs)

        async def sleep(delay: float) -> None:
            sleeps.append(delay)

        client._sleep = sleep
        made.append(client)
        return client

    yield make
    for client in made:
        await client.aclose()


@pytest.fixture
def outbox_path(tmp_path: Path) -> Path:
    return tmp_path / "outbox.db"
