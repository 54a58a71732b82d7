"""What the HMI's routers share: the error they raise, the request bodies, the session check.

Leaf module of :mod:`cellctl.hmi.routes` (the routers import it, it imports none of them).
"""

from __future__ import annotations

import hmac
from typing import Any, Literal

from fastapi import Request
from pydantic import BaseModel, ConfigDict, Field, StrictInt, StrictStr, ValidationError

__all__ = [
    "COOKIE",
    "CommandRequest",
    "HttpError",
    "LoginRequest",
    "NonceRequest",
    "explain",
    "need_user",
    "session_of",
]

COOKIE = "cellctl_hmi"


class HttpError(Exception):
    def __init__(self, code: int, message: str, **extra: Any) -> None:
        self.code, self.message, self.extra = code, message, extra
        super().__init__(message)


# --- request bodies (also the OpenAPI schema) ---------------------------------------------------


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class LoginRequest(_Body):
    user: StrictStr = Field(max_length=64)
    password: StrictStr = Field(max_length=256)


class CommandRequest(_Body):
    """A cellctl/Command without ``request_id``/``user`` (the HMI sets both from the login)."""

    type: Literal["cellctl/Command"] = "cellctl/Command"
    v: Literal[1] = 1
    # strict: "1" or true is not a command code (JSON has integers; a client sending strings is confused)
    command: StrictStr | None = None
    cntrl_cmd: StrictInt | None = None
    unit_mode: StrictStr | None = None
    unit_mode_code: StrictInt | None = None
    params: dict[str, Any] = Field(default_factory=dict)
    nonce: str = Field(min_length=16, max_length=64, pattern=r"^[A-Za-z0-9_-]+$", description="fresh per request")


class NonceRequest(_Body):
    nonce: str = Field(min_length=16, max_length=64, pattern=r"^[A-Za-z0-9_-]+$")


# --- sessions ------------------------------------------------------------------------------------


def session_of(hmi: Any, request: Request) -> tuple[Any, str | None]:
    """The request's session of ``hmi`` (its cookie), or ``(None, why)``."""
    return hmi.sessions.get(request.cookies.get(COOKIE))


def need_user(
    hmi: Any, request: Request, nonce: str | None, roles: tuple[str, ...] = ("operator", "maintenance")
) -> Any:
    """The request's session when it may act: logged in, its CSRF token, one of ``roles``, a fresh
    ``nonce`` (None: no nonce, e.g. logout).

    Raises:
        HttpError: 401 (no or an expired session), 403 (CSRF token, role), 409 (a nonce used before).
    """
    s, why = session_of(hmi, request)
    if s is None:
        if why == "expired":
            raise HttpError(401, "your session has expired; log in again", login=True)
        raise HttpError(401, "log in first: commands need an operator or maintenance login", login=True)
    token = request.headers.get("x-csrf-token", "")
    if not token or not hmac.compare_digest(token.encode("utf-8", "replace"), s.csrf.encode()):
        raise HttpError(403, "missing or wrong CSRF token (X-CSRF-Token); reload the page")
    if s.role not in roles:
        raise HttpError(403, f"user {s.user!r} has role {s.role!r}; this needs one of {list(roles)}")
    if nonce is not None and not s.use_nonce(nonce):
        raise HttpError(409, f"request nonce {nonce!r} was used before: a replayed request is refused")
    return s


def explain(err: ValidationError) -> str:
    """One clause per problem: the field, what is wrong, the value sent."""
    out = []
    for e in err.errors():
        loc = ".".join(str(x) for x in e.get("loc", ()))
        msg = str(e["msg"]).removeprefix("Value error, ")
        got = f" (got {e['input']!r})" if loc and not isinstance(e.get("input"), dict) else ""
        out.append(f"{loc + ': ' if loc else ''}{msg}{got}"[:300])
    return "; ".join(out)
