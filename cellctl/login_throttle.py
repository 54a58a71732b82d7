"""Login throttling shared by the OPC UA gateway and the HMI: exponential back-off per (user, address).

Two keys are charged for each wrong password:

- the **(user, client address) pair**: after ``pair_free`` failures every further try of that user
  from that address must wait ``base_s``, then twice as long after each new failure, up to
  ``pair_max_s``. The owner of the account, at another address, is not slowed at all: an attacker
  cannot lock a PLC or an operator out by guessing their password.
- the **client address** (any user): the same, looser (``address_free`` failures, cap
  ``address_max_s``), so spraying many user names from one address is slowed too.

A try during a back-off is refused **without checking the password** (so it costs the attacker the
wait, not us one hash) and does not lengthen the wait. A success clears its pair only: logging into
one's own account does not wipe an address' record.

Log lines are bounded: one WARNING when a key's back-off starts, then one summary each time its
failures reach a power of two (8, 16, 32 … failures), i.e. about 2·log2(N) lines for N guesses,
whatever the rate. Memory is bounded: keys idle for ``forget_s`` are dropped and at most
``max_keys`` are kept (the oldest go first).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["LoginThrottle", "ThrottleConfig", "ThrottleCounters"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


class ThrottleConfig(BaseModel):
    """Back-off of failed logins (``login:`` in the OPC UA gateway and HMI configs)."""

    model_config = ConfigDict(extra="forbid")

    pair_free: int = Field(default=5, ge=1, le=100, description="wrong passwords per (user, address) before back-off")
    address_free: int = Field(default=20, ge=1, le=1000, description="wrong passwords per address (any user) before")
    base_s: float = Field(default=1.0, gt=0, le=60, description="first back-off; it doubles with each new failure")
    pair_max_s: float = Field(default=300.0, gt=0, le=86400, description="longest back-off of a (user, address) pair")
    address_max_s: float = Field(
        default=60.0, gt=0, le=86400, description="longest back-off of an address: its other users wait at most this"
    )
    forget_s: float = Field(default=3600.0, gt=0, le=7 * 86400, description="a key without failures this long is reset")
    max_keys: int = Field(default=10000, ge=100, le=1_000_000, description="keys remembered (oldest dropped)")

    @model_validator(mode="after")
    def _forget_after_backoff(self) -> ThrottleConfig:
        # a key forgotten while it still backs off would hand the attacker a fresh start
        if self.forget_s < max(self.pair_max_s, self.address_max_s):
            raise ValueError(
                f"forget_s {self.forget_s:g} is shorter than the longest back-off "
                f"{max(self.pair_max_s, self.address_max_s):g} s; expected forget_s >= it"
            )
        return self


@dataclass
class ThrottleCounters:
    """What the throttle has seen since start (the OPC UA Admin node and the HMI's /api/health show them)."""

    failures: int = 0
    """Wrong passwords checked."""
    throttled: int = 0
    """Tries refused unchecked because their pair or address was backing off."""
    lockouts: int = 0
    """Back-offs started (a key reaching its free failures)."""


@dataclass
class _Key:
    failures: int = 0
    last: float = 0.0
    refused: int = 0


class LoginThrottle:
    """Exponential login back-off per (user, address) and per address.

    Args:
        cfg: the limits.
        what: how log lines name the service ("OPC UA", "HMI").
        clock: seconds, monotonic (injected so tests charge back-off without sleeping).
    """

    def __init__(self, cfg: ThrottleConfig, what: str, clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self.what = what
        self.counters = ThrottleCounters()
        self._clock = clock
        self._lock = threading.Lock()
        self._keys: OrderedDict[tuple[str, str], _Key] = OrderedDict()

    def _limits(self, kind: str) -> tuple[int, float]:
        c = self.cfg
        return (c.pair_free, c.pair_max_s) if kind == "pair" else (c.address_free, c.address_max_s)

    def _backoff(self, kind: str, failures: int) -> float:
        free, cap = self._limits(kind)
        if failures < free:
            return 0.0
        return min(cap, self.cfg.base_s * 2.0 ** min(failures - free, 60))

    def _entries(self, user: str, address: str) -> list[tuple[str, tuple[str, str]]]:
        # user names are clipped: a 1 MB name must not become a 1 MB key
        return [("pair", ("pair", f"{user[:64]}@{address}")), ("address", ("address", address))]

    def retry_after(self, user: str, address: str) -> float:
        """Seconds before ``user`` may try a password from ``address`` (0: now).

        A positive answer counts as a throttled try: the caller refuses it without checking.
        """
        now = self._clock()
        wait = 0.0
        with self._lock:
            for kind, key in self._entries(user, address):
                k = self._keys.get(key)
                if k is not None:
                    wait = max(wait, k.last + self._backoff(kind, k.failures) - now)
            if wait > 0:
                self.counters.throttled += 1
                for _, key in self._entries(user, address):
                    if key in self._keys:
                        self._keys[key].refused += 1
        return max(0.0, wait)

    def failed(self, user: str, address: str) -> float:
        """Record a wrong password; the back-off it starts (seconds, the longer of pair and address)."""
        now = self._clock()
        wait = 0.0
        lines: list[str] = []
        with self._lock:
            self.counters.failures += 1
            self._forget(now)
            for kind, key in self._entries(user, address):
                k = self._keys.pop(key, None) or _Key()
                self._keys[key] = k  # most recent last: eviction drops the oldest
                k.failures += 1
                k.last = now
                wait = max(wait, self._backoff(kind, k.failures))
                free, cap = self._limits(kind)
                if k.failures == free:
                    self.counters.lockouts += 1
                    lines.append(
                        f"{kind} {key[1]!r} reached {free} wrong passwords: back-off from "
                        f"{self.cfg.base_s:g} s, doubling, up to {cap:g} s"
                    )
                elif k.failures > free and k.failures & (k.failures - 1) == 0:  # a power of two
                    lines.append(
                        f"{kind} {key[1]!r}: {k.failures} wrong passwords, {k.refused} tries refused "
                        f"during back-off; back-off now {self._backoff(kind, k.failures):g} s"
                    )
        if lines:  # one line per event, however many keys it concerns
            log.warning("%s login throttle: %s", self.what, "; ".join(lines))
        return wait

    def succeeded(self, user: str, address: str) -> None:
        """Clear the (user, address) pair (never the address: one's own login must not wipe it)."""
        with self._lock:
            self._keys.pop(self._entries(user, address)[0][1], None)

    def _forget(self, now: float) -> None:
        while self._keys:
            key, k = next(iter(self._keys.items()))
            if now - k.last <= self.cfg.forget_s and len(self._keys) < self.cfg.max_keys:
                break
            del self._keys[key]
