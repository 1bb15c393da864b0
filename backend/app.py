"""The FastAPI application factory. Imports no torch (see tests/backend/test_app.py)."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from uvicorn.middleware.proxy_headers import ProxyHeadersMiddleware

from backend.api import docs, errors, frontend, openapi
from backend.api.hot_path import AnnotatorHotPath
from backend.api.limits import BodySizeLimit
from backend.api.main import api_router
from backend.api.security_headers import SecurityHeaders
from backend.db.session import create_engine_from_url, make_session_factory, read_only_engine
from backend.services.accounts.auth_cache import AuthCache, watch_user_changes
from backend.services.accounts.login_limits import LoginLimiter, LoginPolicy
from backend.services.captures.storage import LocalDiskStorage, Storage
from backend.services.jobs.jobs import JobQueue
from backend.settings import Settings, get_settings

logger = logging.getLogger(__name__)


def create_app(settings: Settings | None = None, *, job_queue: JobQueue | None = None,
               storage: Storage | None = None) -> FastAPI:
    settings = settings or get_settings()
    # docs_url=None: FastAPI's page loads Swagger UI from a CDN; backend.api.docs serves it from here.
    app = FastAPI(title="handloop", version="0.1.0", docs_url=None, redoc_url=None, openapi_url="/openapi.json",
                  lifespan=_lifespan,
                  description="Human-in-the-loop 3D hand labeling (FreiHAND's procedure): annotator and "
                  "reviewer queues with leases, bootstrap rounds, jobs.")
    url = settings.resolved_database_url
    if url.startswith("sqlite"):
        settings.data_dir.mkdir(parents=True, exist_ok=True)
    engine = create_engine_from_url(url, pool_size=settings.db_pool_size, max_overflow=settings.db_max_overflow)
    app.state.settings = settings
    app.state.engine = engine
    app.state.session_factory = make_session_factory(engine)
    app.state.read_session_factory = make_session_factory(read_only_engine(engine))
    app.state.auth_cache = AuthCache(settings.auth_cache_seconds)
    watch_user_changes(app.state.session_factory, app.state.auth_cache)
    app.state.login_limiter = LoginLimiter(LoginPolicy.from_settings(settings))
    if job_queue is None:
        from backend.broker.celery_queue import CeleryJobQueue  # deferred: celery, kombu: only for a broker's queue

        job_queue = CeleryJobQueue(settings)
    app.state.job_queue = job_queue
    app.state.storage = storage or LocalDiskStorage(settings.storage_dir)
    errors.install(app)
    openapi.install(app)
    app.include_router(api_router)
    docs.mount(app)
    frontend.mount(app)  # the UI at / and viser's client at /viewer/, after the API routes
    app.add_middleware(AnnotatorHotPath)  # innermost: inside the body limit and the security headers
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_upload_bytes)
    app.add_middleware(SecurityHeaders)  # the body limit's 413 gets the headers too
    if settings.trusted_proxies:  # outermost: every layer sees the client's address (uvicorn's own is off)
        app.add_middleware(ProxyHeadersMiddleware, trusted_hosts=settings.trusted_proxies)
    return app


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Start the job queue's outbox (re-sends jobs whose hand-off to the broker failed) while serving."""
    queue = app.state.job_queue
    start = getattr(queue, "start", None)
    if start is not None:
        start(app.state.session_factory)
    try:
        yield
    finally:
        stop = getattr(queue, "stop", None)
        if stop is not None:
            stop()
