"""Fixtures of the client's tests against the real service.

In-process tests use the shared app fixtures (``tests/support/fixtures.py``: every test on
SQLite and on PostgreSQL, unless ``one_engine``) and talk to ``create_app()`` through
``httpx.ASGITransport``; the sync client gets the same through ``PortalTransport``.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from contextlib import ExitStack
from typing import Any

import anyio.from_thread
import httpx
import pytest
from attune_client import AsyncClient, Client
from attune_client._retry import Backoff
from fastapi import FastAPI

from tests.support.fixtures import MakeKey

BASE_URL = "http://attune.test"


class PortalTransport(httpx.BaseTransport):
    """A sync transport that runs ``httpx.ASGITransport`` on an event loop in a thread."""

    def __init__(self, app: FastAPI) -> None:
        self._asgi = httpx.ASGITransport(app=app)
        self._stack = ExitStack()
        self._portal = self._stack.enter_context(anyio.from_thread.start_blocking_portal())
        self.down = False

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        if self.down:
            raise httpx.ConnectError("the service is out of reach", request=request)
        body = request.read()

        async def call() -> httpx.Response:
            inner = httpx.Request(
                request.method, request.url, headers=request.headers, content=body
            )
            response = await self._asgi.handle_async_request(inner)
            content = await response.aread()
            return httpx.Response(
                response.status_code, headers=response.headers, content=content, request=request
            )

        return self._portal.call(call)

    def close(self) -> None:
        pass  # a client closing does not stop the portal: other clients may share it

    def shutdown(self) -> None:
        self._stack.close()


class SwitchTransport(httpx.AsyncBaseTransport):
    """``httpx.ASGITransport`` with a switch: while ``down``, nothing answers."""

    def __init__(self, app: FastAPI) -> None:
        self._asgi = httpx.ASGITransport(app=app)
        self.down = False

    async def handle_async_request(self, request: httpx.Request) -> httpx.Response:
        if self.down:
            raise httpx.ConnectError("the service is out of reach", request=request)
        return await self._asgi.handle_async_request(request)


def fast(client: Any) -> Any:
    """Short backoffs for tests (the rules stay the same)."""
    client._backoff = Backoff(initial=0.01, maximum=0.02)
    return client


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture
def switch(app: FastAPI) -> SwitchTransport:
    return SwitchTransport(app)


@pytest.fixture
async def robot(switch: SwitchTransport, make_key: MakeKey) -> AsyncIterator[AsyncClient]:
    """An ``AsyncClient`` with a robot key of fleet ``default``, in-process."""
    async with fast(AsyncClient(BASE_URL, make_key("robot"), transport=switch)) as client:
        yield client


@pytest.fixture
async def admin(app: FastAPI, make_key: MakeKey) -> AsyncIterator[AsyncClient]:
    """An ``AsyncClient`` with an admin key, in-process."""
    transport = httpx.ASGITransport(app=app)
    async with fast(AsyncClient(BASE_URL, make_key("admin"), transport=transport)) as client:
        yield client


@pytest.fixture
def portal(app: FastAPI) -> Iterator[PortalTransport]:
    transport = PortalTransport(app)
    yield transport
    transport.shutdown()


@pytest.fixture
def sync_robot(portal: PortalTransport, make_key: MakeKey) -> Iterator[Client]:
    """A sync ``Client`` with a robot key, in-process."""
    with fast(Client(BASE_URL, make_key("robot"), transport=portal)) as client:
        yield client
