"""The HMI's routes, one router per page or API area, and the guard every request passes.

``cellctl.hmi.server.build_app`` adds them in this order: the guard (errors, middleware), review
(:mod:`cellctl.hmi.review_api`), session, cell, events, records, pages.
"""

from cellctl.hmi.routes.cell import cell_router
from cellctl.hmi.routes.common import COOKIE, HttpError, need_user
from cellctl.hmi.routes.events import events_router
from cellctl.hmi.routes.guard import add_error_handlers, add_guard
from cellctl.hmi.routes.pages import PAGES, pages_router
from cellctl.hmi.routes.records import records_router
from cellctl.hmi.routes.session import session_router

__all__ = [
    "COOKIE",
    "PAGES",
    "HttpError",
    "add_error_handlers",
    "add_guard",
    "cell_router",
    "events_router",
    "need_user",
    "pages_router",
    "records_router",
    "session_router",
]
