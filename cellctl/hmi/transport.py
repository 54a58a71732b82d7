"""How uvicorn serves the HMI: slow-client deadlines, header size, proxies and connections from the HMI config.

uvicorn closes a kept-alive connection that stays idle (``timeout_keep_alive``) but sets no deadline
on a request that is *being* received: a client that trickles its headers (or its body) one byte at
a time holds a connection, and a task, as long as it likes. :class:`DeadlineH11Protocol` gives each
request ``header_timeout_s`` from its first byte (or from the connection's opening) until its body
is complete; past it the connection is closed.
"""

from __future__ import annotations

import asyncio
from typing import Any

from uvicorn.protocols.http.h11_impl import H11Protocol

from cellctl.hmi.config import HmiConfig

__all__ = ["DeadlineH11Protocol", "uvicorn_config"]


class DeadlineH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline on receiving each request (headers and body)."""

    request_timeout_s: float = 10.0
    """Set on a subclass by :func:`uvicorn_config` (uvicorn builds protocols with its own arguments)."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._deadline: asyncio.TimerHandle | None = None
        self._arm()  # a connection that never sends a byte is a slow client too

    def _arm(self) -> None:
        if self._deadline is None:
            self._deadline = self.loop.call_later(self.request_timeout_s, self._too_slow)

    def _disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def data_received(self, data: bytes) -> None:
        if self.cycle is None or self.cycle.response_complete:
            self._arm()  # the first bytes of the next request on a kept-alive connection
        super().data_received(data)
        if self.cycle is not None and not self.cycle.more_body:
            self._disarm()  # headers and body are in: the app's time is not the client's

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def _too_slow(self) -> None:
        self._deadline = None
        if self.cycle is not None and not self.cycle.more_body:
            return  # complete after all (the last bytes and the timer raced)
        self.logger.info("closing a connection from %s: request not received within %g s", self.client,
                         self.request_timeout_s)  # fmt: skip
        self.transport.close()


def uvicorn_config(app: Any, hcfg: HmiConfig) -> Any:
    """The ``uvicorn.Config`` of the HMI: no proxy trusted unless configured, bounded heads, deadlines."""
    import uvicorn

    protocol = type("HmiH11Protocol", (DeadlineH11Protocol,), {"request_timeout_s": hcfg.header_timeout_s})
    return uvicorn.Config(
        app,
        host=hcfg.host,
        port=hcfg.port,
        http=protocol,
        log_level="warning",
        access_log=False,
        timeout_graceful_shutdown=1,
        lifespan="off",
        # uvicorn believes X-Forwarded-For from 127.0.0.1 by default: a local client could then claim any
        # address (to dodge the per-address login limit and forge the journal's client)
        proxy_headers=bool(hcfg.trusted_proxies),
        forwarded_allow_ips=list(hcfg.trusted_proxies) or None,
        timeout_keep_alive=hcfg.keepalive_s,
        h11_max_incomplete_event_size=hcfg.max_header_bytes,
        limit_concurrency=hcfg.max_connections,
    )
