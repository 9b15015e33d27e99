"""The HTTP face of :class:`~rdd.serve.service.DecomposeService`: a FastAPI app with the official
server's routes (``POST /decompose``, ``GET /config``) and ``GET /health``.

Errors answer ``{"error": "<field>: <what is wrong>"}``: 422 for a malformed body or a bad value,
400 for an unknown method (the official server's status), 403 for a path outside ``--root``, 404
for a file that does not exist, 413 for a body over ``max_body_bytes`` (:mod:`rdd.serve.body_limit`). The handlers are plain functions, which FastAPI runs in its thread
pool; the service lets one request compute at a time per worker.
"""

# No `from __future__ import annotations`: FastAPI reads the handlers' annotations at run time,
# and the request model is local to create_app.
import logging
import os
import sys
import time
from typing import Any

from rdd.serve.body_limit import DEFAULT_MAX_BODY_BYTES, BodyLimit
from rdd.serve.service import DecomposeService, RequestError


def _fastapi():
    """FastAPI and pydantic, or the install line to run."""
    try:
        import fastapi
        import pydantic
    except ImportError as exc:
        raise ImportError(f"serving needs FastAPI and uvicorn: pip install 'rdd[serve]' ({exc})") from exc
    return fastapi, pydantic


def _field(loc: tuple) -> str:
    """``("body", "paths", 0, 1)`` as ``paths[0][1]``; the body itself (``("body", 7)``: not JSON) as ``body``."""
    parts = list(loc[1:]) if loc and loc[0] == "body" else list(loc)
    if not parts or not isinstance(parts[0], str):
        return "body"
    out = parts[0]
    for p in parts[1:]:
        out += f"[{p}]" if isinstance(p, int) else f".{p}"
    return out


# One line per request on stderr, in every worker process (uvicorn's own access log is off: it names
# neither the method asked for nor the frames, and shows only with -v).
REQUEST_LOG = logging.getLogger("rdd.serve.requests")


def _request_log() -> logging.Logger:
    """:data:`REQUEST_LOG`, writing ``time pid client METHOD PATH status seconds [what]`` lines to stderr."""
    if not REQUEST_LOG.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%Y-%m-%d %H:%M:%S"))
        REQUEST_LOG.addHandler(handler)
        REQUEST_LOG.setLevel(logging.INFO)
        REQUEST_LOG.propagate = False
    return REQUEST_LOG


def create_app(service: DecomposeService, max_body_bytes: int = DEFAULT_MAX_BODY_BYTES):
    """A FastAPI app answering with ``service`` (loaded before, once per worker); bodies over
    ``max_body_bytes`` answer 413; each request is logged in one line (:data:`REQUEST_LOG`)."""
    fastapi, pydantic = _fastapi()
    requests_log = _request_log()
    from fastapi.exceptions import RequestValidationError
    from fastapi.responses import JSONResponse

    class DecomposeRequest(pydantic.BaseModel):
        """The official request body; ``preprocessor`` is optional here (the official default is r3m)."""

        model_config = pydantic.ConfigDict(strict=True)
        paths: list[list[str]]
        method: str
        preprocessor: str | None = None

    app = fastapi.FastAPI(title="rdd decomposition server")
    # around the routes, so an oversized body is refused before FastAPI reads or parses any of it
    app.add_middleware(BodyLimit, max_bytes=max_body_bytes)
    app.state.service = service

    @app.middleware("http")
    async def _log(request, call_next):
        start = time.perf_counter()
        status = 500
        try:
            response = await call_next(request)
            status = response.status_code
            return response
        finally:
            what = getattr(request.state, "what", "")
            client = request.client.host if request.client else "-"
            requests_log.info("pid %d %s %s %s %d %.3f s%s", os.getpid(), client, request.method,
                              request.url.path, status, time.perf_counter() - start, f" ({what})" if what else "")

    @app.exception_handler(RequestValidationError)
    def _invalid(_request, exc: RequestValidationError) -> JSONResponse:
        first = exc.errors()[0]
        msg = f"{_field(tuple(first.get('loc', ())))}: {first.get('msg', 'invalid')}"
        return JSONResponse({"error": msg}, status_code=422)

    @app.exception_handler(RequestError)
    def _bad(_request, exc: RequestError) -> JSONResponse:
        return JSONResponse({"error": str(exc)}, status_code=exc.status)

    @app.post("/decompose")
    def decompose(request: DecomposeRequest, http: fastapi.Request) -> dict[str, Any]:
        http.state.what = f"{request.method}, {len(request.paths)} frames"
        answer = service.decompose(request.paths, request.method, request.preprocessor)
        http.state.what += f", {len(answer['segments'])} segments"
        return answer

    @app.get("/config")
    def config() -> dict[str, Any]:
        return {"config": service.config()}

    @app.get("/health")
    def health() -> dict[str, Any]:
        return {"status": "ok", "pid": os.getpid(), "methods": list(service.decomposers)}

    return app
