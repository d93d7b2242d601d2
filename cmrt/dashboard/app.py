"""The dashboard's web server: Starlette routes over :mod:`cmrt.dashboard.data`, served by uvicorn.

Read-only: every request opens the store as the read verbs do (``open_store(path, readonly=True)``: a
read-only SQLite URI, or a private copy of a store at rest) and closes it, so a worker's progress shows on the
next request and nothing is ever written into the store. The one write is a rendered clip, cached in a directory
of this user's that the dashboard owns (:mod:`cmrt.dashboard.clipcache`), never beside the store, and read back
only as a regular file it wrote. Other files are served from a fixed list (the package's static files and
plotly's bundled ``plotly.min.js``), never from a path taken from the URL. A request whose ``Host`` is not the
address served (a DNS-rebinding page's name) is refused (400) before any route runs. Bad input is a 4xx page
(JSON under ``/api/``) with one line, never a traceback: an unknown run or route 404, a bad query 400, a damaged
store 422; a clip that cannot be rendered or cached here (no OpenGL backend, a full disk) 503.
"""

from __future__ import annotations

import contextlib
import errno
import html
import ipaddress
import socket
import sqlite3
import string
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import plotly
import uvicorn
from starlette.applications import Starlette
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response
from starlette.routing import Route
from starlette.types import ASGIApp, Receive, Scope, Send

from cmrt import inputs
from cmrt.dashboard import clipcache, data
from cmrt.errors import CmrtError, DiskFull
from cmrt.service.store import Store, open_store

PACKAGE = resources.files("cmrt.dashboard")
PLOTLY_JS = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
#: every file the server sends, by URL name: nothing else on disk is reachable through a URL
STATIC_FILES: dict[str, tuple[str, str]] = {
    "dashboard.js": ("static/dashboard.js", "text/javascript"),
    "dashboard.css": ("static/dashboard.css", "text/css"),
}
PAGES = ("index", "run", "compare")
REASONS = {400: "Bad Request", 404: "Not Found", 405: "Method Not Allowed", 422: "Store Unreadable",
           500: "Internal Error", 503: "Cannot Render Here"}


@dataclass(frozen=True)
class DashboardConfig:
    """What ``cmrt dashboard`` serves and where (defaults: the CLI's)."""

    store_path: Path
    host: str = "127.0.0.1"
    port: int = 8080  # 0: any free port (the URL printed names it)
    clip_fps: int = 30  # frame rate of rendered clips
    cache_dir: Path | None = None  # where rendered clips are kept (None: clipcache.default_dir(), this user's)


@dataclass
class _State:
    config: DashboardConfig
    sims: data.SimCache = field(default_factory=data.SimCache)
    pages: dict[str, str] = field(default_factory=dict)


def _error_page(status: int, message: str) -> str:
    page = string.Template((PACKAGE / "templates" / "error.html").read_text())
    return page.substitute(status=status, reason=REASONS.get(status, "Error"), message=html.escape(message))


def _error(request: Request, status: int, message: str) -> Response:
    """The one shape of a refusal: one line, JSON under /api/, an HTML page elsewhere."""
    message = inputs.one_line(message)
    if request.url.path.startswith("/api/"):
        return JSONResponse({"error": message, "status": status}, status_code=status)
    return HTMLResponse(_error_page(status, message), status_code=status)


def _status_of(exc: Exception) -> tuple[int, str]:
    if isinstance(exc, data.NotFound):
        return 404, str(exc)
    if isinstance(exc, CmrtError):
        return 422, str(exc)
    if isinstance(exc, DiskFull):
        return 503, str(exc)
    if isinstance(exc, sqlite3.DatabaseError):
        return 422, f"the store is damaged: {exc}"
    return 500, f"{type(exc).__name__}: {exc}"


def _run_id(request: Request) -> int:
    """The run id of the URL; an id no run can have (0, past 2**63) is not found."""
    run_id = request.path_params["run_id"]
    if not inputs.RUN_ID.contains(run_id):
        raise data.NotFound(f"no run {run_id} in this store")
    return run_id


def _run_ids(request: Request) -> list[int]:
    """``?runs=1,2,3``."""
    text = request.query_params.get("runs", "")
    ids = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        if not inputs.is_run_id(item):
            raise HTTPException(400, f"runs must be run ids separated by commas, got {inputs.shown(item)}")
        ids.append(int(item))
    return ids


def _with_store(handler: Callable[[Request, Store], Response]) -> Callable[[Request], Response]:
    """A route that reads the store: opened read-only for this request only, closed after it."""

    def endpoint(request: Request) -> Response:
        state: _State = request.app.state.dashboard
        try:
            with open_store(state.config.store_path, readonly=True) as store:
                return handler(request, store)
        except HTTPException:
            raise
        except (CmrtError, DiskFull, sqlite3.DatabaseError) as exc:
            return _error(request, *_status_of(exc))

    endpoint.__name__ = handler.__name__
    return endpoint


def _page(name: str) -> Callable[[Request, Store], Response]:
    def show(request: Request, store: Store) -> Response:
        if name == "run":
            data.find_run(store, _run_id(request))
        elif name == "compare":
            for run_id in _run_ids(request):
                data.find_run(store, run_id)
        pages = request.app.state.dashboard.pages
        if name not in pages:
            pages[name] = (PACKAGE / "templates" / f"{name}.html").read_text()
        return HTMLResponse(pages[name])

    show.__name__ = f"{name}_page"
    return show


def api_runs(request: Request, store: Store) -> Response:
    return JSONResponse(data.runs_table(store))


def api_run(request: Request, store: Store) -> Response:
    return JSONResponse(data.run_page(store, _run_id(request)))


def api_traces(request: Request, store: Store) -> Response:
    return JSONResponse(data.run_traces(store, _run_id(request), request.app.state.dashboard.sims))


def api_compare(request: Request, store: Store) -> Response:
    return JSONResponse(data.compare(store, _run_ids(request), request.app.state.dashboard.sims))


def clip(request: Request, store: Store) -> Response:
    """The run's MP4, rendered on the first request; 503 with the reason where no OpenGL backend loads."""
    run_id = _run_id(request)
    data.find_run(store, run_id)
    config: DashboardConfig = request.app.state.dashboard.config
    try:
        video = data.clip(store, run_id, config.clip_fps, config.cache_dir or clipcache.default_dir())
    except (clipcache.Unavailable, DiskFull) as exc:  # a damaged store's CmrtError stays a 422
        return _error(request, 503, str(exc))
    return Response(video, media_type="video/mp4")


def static(request: Request) -> Response:
    """One of :data:`STATIC_FILES` (or plotly's bundle); any other name, ``..`` included, is not found."""
    name = request.path_params["name"]
    if name == "plotly.min.js" and PLOTLY_JS.is_file():
        return FileResponse(PLOTLY_JS, media_type="text/javascript")
    if name not in STATIC_FILES:
        return _error(request, 404, "no such file")
    rel, media = STATIC_FILES[name]
    return Response((PACKAGE / rel).read_bytes(), media_type=media)


async def _http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, HTTPException)
    return _error(request, exc.status_code, "no such page" if exc.status_code == 404 else str(exc.detail))


async def _server_error(request: Request, exc: Exception) -> Response:
    print(f"cmrt dashboard: {request.url.path}: {type(exc).__name__}: {inputs.one_line(str(exc))}", file=sys.stderr)
    return _error(request, 500, f"{type(exc).__name__}: {exc}")


def create_app(config: DashboardConfig) -> Starlette:
    """The dashboard as an ASGI application (tests drive it in-process; :func:`serve` runs it)."""
    routes = [
        Route("/", _with_store(_page("index"))),
        Route("/runs/{run_id:int}", _with_store(_page("run"))),
        Route("/compare", _with_store(_page("compare"))),
        Route("/api/runs", _with_store(api_runs)),
        Route("/api/runs/{run_id:int}", _with_store(api_run)),
        Route("/api/runs/{run_id:int}/traces", _with_store(api_traces)),
        Route("/api/compare", _with_store(api_compare)),
        Route("/clips/run{run_id:int}.mp4", _with_store(clip)),
        Route("/static/{name}", static),
    ]
    app = Starlette(routes=routes, exception_handlers={HTTPException: _http_error, Exception: _server_error},
                    middleware=[Middleware(ServedHostMiddleware, allowed_hosts=allowed_hosts(config.host))])
    app.state.dashboard = _State(config)
    return app


class ServedHostMiddleware:
    """Starlette's TrustedHostMiddleware over :func:`allowed_hosts`, that also lets in a ``Host`` naming the very
    address the connection came in on (``scope["server"]``): a server on 0.0.0.0 reached at one of this machine's
    LAN addresses that its name does not resolve to. A DNS-rebinding page sends its own name, never an address."""

    def __init__(self, app: ASGIApp, allowed_hosts: list[str]):
        self.app, self.trusted = app, TrustedHostMiddleware(app, allowed_hosts=allowed_hosts)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        server = scope.get("server") if scope["type"] in ("http", "websocket") else None
        host = Headers(scope=scope).get("host", "") if server else ""
        name = host[1:].partition("]")[0] if host.startswith("[") else host.rpartition(":")[0] or host
        if server and name and name.lower() == str(server[0]).lower():
            await self.app(scope, receive, send)
        else:
            await self.trusted(scope, receive, send)


LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")


def allowed_hosts(host: str) -> list[str]:
    """The ``Host`` names a request may carry: the address served (as given and as it resolves) and, for the
    loopback, ``localhost`` and its addresses; for a wildcard address (0.0.0.0, ::) also this machine's names
    and their addresses. Any other name - a page's own, pointed at this address by DNS rebinding - is refused:
    the browser would otherwise hand that page the store."""
    names = {host}
    with contextlib.suppress(OSError, UnicodeError, ValueError):
        names |= {info[4][0] for info in socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)}
    if any(_is(name, "is_loopback") for name in names) or host == "localhost":
        names |= set(LOOPBACK_NAMES)
    if any(_is(name, "is_unspecified") for name in names):
        names |= {*LOOPBACK_NAMES, socket.gethostname(), socket.getfqdn()}
        with contextlib.suppress(OSError, UnicodeError, ValueError):
            names |= {info[4][0] for info in socket.getaddrinfo(socket.gethostname(), None, type=socket.SOCK_STREAM)}
    names = {name.lower().split("%")[0] for name in names if name}
    return sorted(names | {f"[{name}]" for name in names if ":" in name})  # an IPv6 address in a Host: [::1]


def _is(name: str, kind: str) -> bool:
    try:
        return getattr(ipaddress.ip_address(name.split("%")[0]), kind)
    except ValueError:
        return False


def bind(config: DashboardConfig) -> socket.socket:
    """The listening socket, or a one-line CmrtError: a host that does not resolve or is not this machine's, a
    port in use or not allowed."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(config.host, config.port, type=socket.SOCK_STREAM)[0]
    except (socket.gaierror, UnicodeError, ValueError) as exc:
        raise CmrtError(f"--host {inputs.shown(config.host)}: cannot resolve it ({exc})") from None
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(128)
    except OSError as exc:
        sock.close()
        why = {errno.EADDRINUSE: "the port is in use (choose another with --port, or 0 for any free one)",
               errno.EACCES: "not allowed (ports below 1024 need privileges)",
               errno.EADDRNOTAVAIL: "the address is not one of this machine's"}.get(exc.errno, exc.strerror)
        raise CmrtError(f"cannot listen on {inputs.shown(config.host)} port {config.port}: {why}") from None
    sock.set_inheritable(True)
    return sock


def url_of(sock: socket.socket) -> str:
    host, port = sock.getsockname()[:2]
    return f"http://{f'[{host}]' if ':' in host else host}:{port}/"


def serve(config: DashboardConfig, sock: socket.socket) -> None:
    """Serve until Ctrl-C (uvicorn, quiet: errors only)."""
    server = uvicorn.Server(uvicorn.Config(create_app(config), log_level="warning", access_log=False,
                                           lifespan="off", timeout_graceful_shutdown=2))
    server.run(sockets=[sock])
