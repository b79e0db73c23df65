"""Exports over HTTP: admitted before any work (``Readers.gate``: 429/503 with Retry-After), encoded on an
export thread, and cut off when the client stops reading; history reads on the readers' own threads and
pool (backend/services/telemetry/readers.py).

A download that accepts no data for ``FLEET_EXPORT_STALL_TIMEOUT_S`` is cut off: the response stops, the
export's thread stops at its next write and its slot is free at once. (The server then closes the
connection; the bytes already in its buffers go out if the client reads again.)
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Mapping
from typing import IO, Any, TypeVar

from fastapi import Request
from fastapi.responses import Response, StreamingResponse
from pydantic import BaseModel
from sqlalchemy.exc import DBAPIError
from starlette.types import Send

from backend.core.errors import ServiceError
from backend.services.lifecycle import Services
from backend.services.telemetry.readers import ExportSlot, ExportStream, Readers
from backend.store.db import is_read_timeout

log = logging.getLogger(__name__)

T = TypeVar("T")

#: what an export route may answer beyond its own errors (for ``responses=``)
EXPORT_REFUSALS: dict[int | str, dict[str, Any]] = {
    429: {
        "description": "this client runs FLEET_EXPORT_MAX_PER_CLIENT exports already (code too_many_exports; "
        "see Retry-After)"
    },
    503: {
        "description": "the server runs FLEET_EXPORT_MAX_CONCURRENT exports already (code exports_busy; see "
        "Retry-After), or a read ran past FLEET_READER_STATEMENT_TIMEOUT_S (code read_timeout)"
    },
}


def export_client(request: Request) -> str:
    """Who an export counts against: the caller (user or token) from its address."""
    principal = getattr(request.state, "principal", None)
    subject = principal.subject if principal is not None else "anonymous"
    host = request.client.host if request.client else ""
    return f"{subject}@{host}"


def admit(services: Services, request: Request) -> ExportSlot:
    """A place for one export, or 429/503 with Retry-After before anything is read."""
    return services.readers.gate.admit(export_client(request))


def read_timed_out(readers: Readers) -> ServiceError:
    return ServiceError(
        503,
        f"the read ran longer than FLEET_READER_STATEMENT_TIMEOUT_S ({readers.statement_timeout_s:g} s) and "
        "was stopped: narrow start/end, or read fewer points",
        "read_timeout",
    )


async def read(services: Services, fn: Callable[..., T], *args: Any) -> T:
    """A history read on the readers' threads; one that ran past the statement timeout is a 503."""
    try:
        return await services.readers.run(fn, *args)
    except DBAPIError as exc:
        if is_read_timeout(exc):
            raise read_timed_out(services.readers) from None
        raise


async def read_json(services: Services, fn: Callable[..., BaseModel], *args: Any) -> Response:
    """A history read answered as JSON encoded on the readers' thread too. FastAPI validates and encodes a
    returned model on the event loop: the whole fleet's five minutes (ten series of 1000 points, 1.5 MB) took
    60-180 ms there, the loop stalls the soak saw (bench/bench_soak.py). The body is the same bytes."""

    def encoded() -> bytes:
        return fn(*args).model_dump_json().encode()

    return Response(content=await read(services, encoded), media_type="application/json")


class ExportResponse(StreamingResponse):
    """Streams an ExportStream; gives back its slot when done, failed, disconnected or cut off."""

    def __init__(
        self,
        stream: ExportStream,
        *,
        slot: ExportSlot,
        readers: Readers,
        media_type: str,
        headers: Mapping[str, str],
    ) -> None:
        super().__init__(stream, media_type=media_type, headers=headers)
        self._stream = stream
        self._slot = slot
        self._readers = readers

    async def _send(self, send: Send, message: Any) -> None:
        await asyncio.wait_for(send(message), self._readers.stall_timeout_s)

    async def stream_response(self, send: Send) -> None:
        try:
            await send({"type": "http.response.start", "status": self.status_code, "headers": self.raw_headers})
            async for chunk in self.body_iterator:
                await self._send(send, {"type": "http.response.body", "body": chunk, "more_body": True})
            await self._send(send, {"type": "http.response.body", "body": b"", "more_body": False})
        except TimeoutError:
            self._readers.gate.counters.cut_stalled += 1
            log.warning(
                "export to %s cut off: it accepted no data for %g s (FLEET_EXPORT_STALL_TIMEOUT_S)",
                self._slot.client,
                self._readers.stall_timeout_s,
            )
        except Exception:
            self._readers.gate.counters.failed += 1
            raise
        finally:
            self._stream.cancel()
            self._slot.release()


def export_response(
    services: Services,
    slot: ExportSlot,
    produce: Callable[[IO[bytes]], object],
    *,
    what: str,
    media_type: str,
    headers: Mapping[str, str],
) -> ExportResponse:
    readers = services.readers
    return ExportResponse(
        readers.stream(produce, what), slot=slot, readers=readers, media_type=media_type, headers=headers
    )
