"""Logins of the HMI: password hashes, sessions with CSRF tokens (login back-off: cellctl.login_throttle).

Passwords are stored only as ``scrypt$n$r$p$salt$hash`` (``hashlib.scrypt``, n=2^14, r=8, p=1:
~16 MB and ~50 ms per check, which also slows guessing). A session is a random token in an
``HttpOnly``/``SameSite=Strict`` cookie; each session has its own CSRF token that every
state-changing request must echo in ``X-CSRF-Token``, and a set of nonces already used, so a
captured request cannot be replayed within the session either. Everything is in memory: an HMI
restart logs everybody out, which is the safe side.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

from cellctl.errors import ConfigError

__all__ = ["Session", "SessionStore", "hash_password", "verify_password"]

_SCRYPT = {"n": 1 << 14, "r": 8, "p": 1}
NONCES_KEPT = 4096
"""Nonces remembered per session; older ones age out with the session (a shift is far fewer)."""


def _b64(b: bytes) -> str:
    return base64.urlsafe_b64encode(b).decode().rstrip("=")


def _unb64(s: str) -> bytes:
    return base64.urlsafe_b64decode(s + "=" * (-len(s) % 4))


def hash_password(password: str, *, salt: bytes | None = None) -> str:
    """The storable hash of ``password`` (random salt unless one is given, for tests).

    Raises:
        ConfigError: the password is shorter than 8 characters.
    """
    if len(password) < 8:
        raise ConfigError(f"password too short ({len(password)} characters); expected at least 8")
    salt = salt if salt is not None else secrets.token_bytes(16)
    n, r, p = _SCRYPT["n"], _SCRYPT["r"], _SCRYPT["p"]
    digest = hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p, dklen=32)
    return f"scrypt${n}${r}${p}${_b64(salt)}${_b64(digest)}"


def verify_password(password: str, stored: str) -> bool:
    """True if ``password`` matches ``stored`` (constant-time compare; a malformed hash is False)."""
    try:
        kind, *rest = stored.split("$")
        if kind == "scrypt":
            n, r, p, salt, want = int(rest[0]), int(rest[1]), int(rest[2]), _unb64(rest[3]), _unb64(rest[4])
            got = hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p, dklen=len(want), maxmem=1 << 27)
        elif kind == "pbkdf2_sha256":
            iters, salt, want = int(rest[0]), _unb64(rest[1]), _unb64(rest[2])
            got = hashlib.pbkdf2_hmac("sha256", password.encode(), salt, iters, dklen=len(want))
        else:
            return False
    except (ValueError, IndexError):
        return False
    return hmac.compare_digest(got, want)


@dataclass
class Session:
    """One logged-in user."""

    token: str
    user: str
    role: str
    csrf: str
    created: float
    last_seen: float
    nonces: OrderedDict[str, None] = field(default_factory=OrderedDict)

    def use_nonce(self, nonce: str) -> bool:
        """Record ``nonce``; False if this session used it before (a replayed request)."""
        if nonce in self.nonces:
            return False
        self.nonces[nonce] = None
        while len(self.nonces) > NONCES_KEPT:
            self.nonces.popitem(last=False)
        return True


class SessionStore:
    """Sessions by token, expiring after ``idle_s`` without a request or ``max_s`` after login.

    Args:
        clock: seconds, monotonic (injected so expiry is testable without sleeping).
    """

    def __init__(self, idle_s: float, max_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.idle_s = idle_s
        self.max_s = max_s
        self._clock = clock
        self._lock = threading.Lock()
        self._sessions: dict[str, Session] = {}

    def create(self, user: str, role: str) -> Session:
        now = self._clock()
        s = Session(secrets.token_urlsafe(32), user, role, secrets.token_urlsafe(32), now, now)
        with self._lock:
            self._purge(now)
            self._sessions[s.token] = s
        return s

    def get(self, token: str | None) -> tuple[Session | None, str | None]:
        """The live session of ``token`` (touching it), or None and why not ("expired", "unknown")."""
        if not token:
            return None, None
        now = self._clock()
        with self._lock:
            s = self._sessions.get(token)
            if s is None:
                return None, "unknown"
            if now - s.last_seen > self.idle_s or now - s.created > self.max_s:
                del self._sessions[token]
                return None, "expired"
            s.last_seen = now
            return s, None

    def drop(self, token: str | None) -> None:
        with self._lock:
            self._sessions.pop(token or "", None)

    def _purge(self, now: float) -> None:
        dead = [t for t, s in self._sessions.items() if now - s.last_seen > self.idle_s or now - s.created > self.max_s]
        for t in dead:
            del self._sessions[t]
