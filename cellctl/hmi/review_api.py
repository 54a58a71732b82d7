"""The review's REST endpoints (the Review page and an MES use the same ones).

Reading needs no login, like every record of the HMI; a decision and a release need an
``operator`` or ``qa`` session, its CSRF token and a fresh nonce (the server's ``need_user``),
and every error is ``{"error": ...}``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal

from fastapi import FastAPI, Query, Request
from fastapi import Path as FastApiPath
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field, StrictStr

from cellctl.hmi.review import REVIEWERS, Conflict, Review

__all__ = ["DecisionRequest", "ReleaseRequest", "add_review_routes"]

_NONCE = {"min_length": 16, "max_length": 64, "pattern": r"^[A-Za-z0-9_-]+$"}
ImageNo = Annotated[int, FastApiPath(ge=0, le=1_000_000)]


class DecisionRequest(BaseModel):
    """An operator's answer for one view: what it is, and why."""

    model_config = ConfigDict(extra="forbid")

    label: Literal["clean", "dirty"]
    reason: StrictStr = Field(min_length=3, max_length=500, description="why (what the operator saw), in the ledger")
    nonce: str = Field(**_NONCE, description="fresh per request")  # type: ignore[arg-type]


class ReleaseRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")

    reason: StrictStr = Field(default="reviewed", min_length=1, max_length=500)
    nonce: str = Field(**_NONCE)  # type: ignore[arg-type]


def add_review_routes(app: FastAPI, hmi: Any, need_user: Callable[..., Any], error: type[Exception]) -> None:
    """Add the review endpoints to ``app``.

    Args:
        hmi: the :class:`~cellctl.hmi.server.Hmi` (its ``review``, ``journal`` and ``link``).
        need_user: the server's session check ``need_user(request, nonce, roles)``.
        error: the server's ``HttpError(code, message)``.
    """
    review: Review = hmi.review

    def conflict(err: Conflict) -> Exception:
        return error(409, str(err))

    @app.get("/api/review/queue", tags=["review"])
    def queue(
        state: Literal["open", "decided", "all"] = "open", limit: int = Query(default=100, ge=1, le=1000)
    ) -> dict[str, Any]:
        """Dirty and uncertain views of the newest completed cycles (``state``: open, decided or all)."""
        return {"items": review.queue(state, limit), "require_for_uncertain": hmi.cfg.review.require_for_uncertain}

    @app.get("/api/review/items/{cycle_id}/{n}", tags=["review"])
    def item(cycle_id: str, n: ImageNo) -> dict[str, Any]:
        """One view of the queue with its decision (null while open) and its cycle's release state."""
        return review.item(cycle_id, n)

    @app.get("/api/review/items/{cycle_id}/{n}/reference", tags=["review"])
    def reference(cycle_id: str, n: ImageNo) -> Response:
        """The reference image of the view's viewpoint (its commissioned set's), checked against the set's
        manifest; 404 when the view has none."""
        return Response(review.reference_image(cycle_id, n), media_type="image/png",
                        headers={"Cache-Control": "max-age=3600"})  # fmt: skip

    @app.post("/api/review/items/{cycle_id}/{n}", tags=["review"])
    def decide(cycle_id: str, n: ImageNo, request: Request, body: DecisionRequest) -> dict[str, Any]:
        """Confirm the view clean or dirty (operator or qa): ledger entry, bank, release state."""
        s = need_user(request, body.nonce, REVIEWERS)
        try:
            out = review.decide(cycle_id, n, body.label, body.reason, s.user, s.role)
        except Conflict as err:
            raise conflict(err) from None
        hmi.journal(kind="review", user=s.user, cycle_id=cycle_id, image=n, label=body.label,
                    entry_hash=out["decision"]["entry_hash"])  # fmt: skip
        hmi.link.note("info", f"{s.user} confirmed view {cycle_id}/{n} {body.label}", f"hmi:{s.user}")
        return out

    @app.get("/api/cycles/{cycle_id}/release", tags=["review"])
    def release_state(cycle_id: str) -> dict[str, Any]:
        """Whether the cycle's verdict is released (auto, review_required, ready, released, not_applicable)."""
        return review.release_state(cycle_id)

    @app.post("/api/cycles/{cycle_id}/release", tags=["review"])
    def release(cycle_id: str, request: Request, body: ReleaseRequest) -> dict[str, Any]:
        """Release the reviewed verdict (operator or qa; every uncertain view decided first)."""
        s = need_user(request, body.nonce, REVIEWERS)
        try:
            out = review.release(cycle_id, s.user, s.role, body.reason)
        except Conflict as err:
            raise conflict(err) from None
        hmi.journal(kind="release", user=s.user, cycle_id=cycle_id, verdict=out["released_verdict"])
        hmi.link.note("info", f"{s.user} released cycle {cycle_id}: {out['released_verdict']}", f"hmi:{s.user}")
        return out

    @app.get("/api/review/bank", tags=["review"])
    def bank() -> dict[str, Any]:
        """Views kept per surface and label, the bound, and how many were evicted."""
        m = review.bank.manifest()
        return {"counts": review.bank.counts(), "max_per_label": review.bank.max_per_label,
                "evicted": m.get("evicted", {}), "ledger": review.ledger.head()}  # fmt: skip
