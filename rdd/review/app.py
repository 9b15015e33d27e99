"""The HTTP face of :class:`~rdd.review.session.ReviewSession`: the page and its JSON API (FastAPI).

Routes: ``GET /`` the page (``static/``), ``GET /api/episodes`` one page of the list,
``GET /api/episode/{name}`` an episode, ``PUT /api/episode/{name}`` the person's version of it,
``POST /api/save`` write ``--out``, ``GET /api/frame/{name}/{view}/{index}`` and
``GET /api/neighbour/{entry}/{begin|end}/{view}`` JPEG frames, ``GET /files/{path}`` a file under
``--data`` or the database (403 outside). Errors answer ``{"error": "<field>: <what is wrong>"}``.
"""

# No `from __future__ import annotations`: FastAPI reads the handlers' annotations at run time.
import threading
from pathlib import Path
from typing import Any

from rdd.review.session import PAGE_SIZE, ReviewError, ReviewSession

STATIC = Path(__file__).resolve().parent / "static"
PAGES = {"": ("index.html", "text/html; charset=utf-8"), "review.js": ("review.js", "text/javascript"),
         "review.css": ("review.css", "text/css")}


def create_app(session: ReviewSession):
    """A FastAPI app over ``session``; one request touches the session at a time."""
    fastapi, pydantic = serve_fastapi()
    from fastapi.responses import FileResponse, JSONResponse, Response

    class Edit(pydantic.BaseModel):
        """The person's version of one episode."""

        model_config = pydantic.ConfigDict(strict=True)
        segments: list[list[int]]
        instructions: list[str]
        reviewed: bool = False

    app = fastapi.FastAPI(title="rdd review", docs_url=None, redoc_url=None, openapi_url=None)
    lock = threading.Lock()

    @app.exception_handler(ReviewError)
    def review_error(_request, exc: ReviewError):
        return JSONResponse({"error": str(exc)}, status_code=exc.status)

    def static(name: str):
        file, kind = PAGES[name]
        return Response((STATIC / file).read_bytes(), media_type=kind, headers={"Cache-Control": "no-store"})

    @app.get("/")
    def index():
        return static("")

    @app.get("/favicon.ico")
    def favicon():
        return Response(status_code=204)

    @app.get("/static/{name}")
    def asset(name: str):
        if name not in PAGES or not name:
            raise ReviewError(f"static/{name}: no such file", status=404)
        return static(name)

    @app.get("/api/episodes")
    def episodes(page: int = 0, size: int = PAGE_SIZE, q: str = "", only: str = "all") -> dict[str, Any]:
        with lock:
            return session.page(page, size, q, only)

    @app.get("/api/episode/{name}")
    def episode(name: str) -> dict[str, Any]:
        with lock:
            return session.episode(name)

    @app.put("/api/episode/{name}")
    def update(name: str, edit: Edit) -> dict[str, Any]:
        with lock:
            return {"record": session.update(name, edit.segments, edit.instructions, edit.reviewed)}

    @app.post("/api/save")
    def save() -> dict[str, Any]:
        with lock:
            return {"saved": str(session.save())}

    def jpeg(data: bytes):
        return Response(data, media_type="image/jpeg", headers={"Cache-Control": "max-age=3600"})

    @app.get("/api/frame/{name}/{view}/{index}")
    def frame(name: str, view: str, index: int):
        with lock:
            return jpeg(session.frame(name, view, index))

    @app.get("/api/neighbour/{entry}/{which}/{view}")
    def neighbour(entry: int, which: str, view: str):
        with lock:
            return jpeg(session.neighbour_frame(entry, which, view))

    @app.get("/files/{path:path}")
    def files(path: str):
        return FileResponse(session.allowed(path))

    return app


def serve_fastapi():
    """FastAPI and pydantic, or the line that installs them (the ``serve`` extra)."""
    try:
        import fastapi
        import pydantic
    except ImportError as exc:
        raise ImportError(f"review needs FastAPI and uvicorn: pip install 'rdd[serve]' ({exc})") from exc
    return fastapi, pydantic
