"""The operator's page, served by the station itself (`btf-host station --http ADDR:PORT`), in
the station's own event loop, with aiohttp.

What it serves:
- `/`: the page (`tools/page/static/`), its command forms generated from the command table
  (`tools.page.forms`); `/?token=T` trades the station's token for a cookie and redirects to `/`.
- `/events`: server-sent events, pushed as things happen: `hello` (everything, on connect and
  after this client fell behind), `snapshot` (`Station.snapshot_json`, after events and every
  second), `cards` (the latest capture at a pose changed), `event` (every station event, the
  robot's answers to the page's commands among them), `rev` (a mask arrived: drawings renewed).
- `/api/state`: the hello as one JSON document.
- `/capture/ID/section`, `/capture/ID/NAME.png`, `/capture/ID/thumb.png`: a capture drawn as
  the report draws it (`tools.page.data`).
- `POST /api/command` `{"name": "GOTO", "fields": {"elevation": "70"}}`: the command to the
  robot; `{"command_id", "answer"}` once it answers (202 and `{"command_id"}` when it takes
  longer; the answer then comes as an event).

Security: the token is drawn from the operating system's random source at start-up and printed
on stderr only (never logged, never sent over the radio). Viewing needs it unless the station
runs with `--http-public`; a state-changing request needs it always (the cookie, or the
`X-BTF-Token` header), a JSON body, and, when the token comes as a cookie, an `Origin` that is
this page's own: a page of another site cannot send commands through the operator's browser.
Every request must name this page in its `Host` header (DNS rebinding). No client can take the
station's descriptors, memory or loop (`tools.page.guard`): connections are capped and must send
their headers in time, event streams are capped overall (STREAMS) and per client address
(STREAMS_PER_CLIENT), each refusal a 503 in one line, counted and said in the station's log.
"""
from __future__ import annotations

import asyncio
import hmac
import json
import secrets
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from aiohttp import web

from tools.page.data import PageData, static_dir
from tools.page.forms import forms_html, parse_form
from tools.page.guard import BODY_TIMEOUT_S, ConnectionGate, HostCheck, QuietLog, Tally, connection_cap
from tools.report.look import CSS
from tools.station.bus import EventBus
from tools.station.events import LostEvent, StationEvent
from tools.station.station import Station

ANSWER_WAIT_S = 2.0  # a command's POST waits this long for the robot's answer
SNAPSHOT_EVERY_S = 1.0
COALESCE_S = 0.05  # events within this go out as one snapshot
RECENT_EVENTS = 80  # the events a page that opens is shown
PAGE_QUEUE = 512  # messages a page may fall behind before it is sent everything again
STREAMS = 32  # event streams open at once (each is pushed every snapshot)
STREAMS_PER_CLIENT = 6  # from one address: a few tabs
STATIC = {"page.js": "application/javascript", "page.css": "text/css"}


@dataclass
class PageOptions:
    host: str = "127.0.0.1"
    port: int = 8765
    public: bool = False  # viewing without the token (commands always need it)
    hosts: tuple[str, ...] = ()  # names the page answers to besides its address (--http-host)
    fake: Any = None  # a fake robot's HalConfig: its renders are the measured frames
    token: str = field(default_factory=lambda: secrets.token_urlsafe(24))


def parse_http(text: str) -> tuple[str, int]:
    """`PORT`, `ADDR:PORT` or `[V6ADDR]:PORT` -> (host, port); ValueError in one line."""
    host, sep, port = text.rpartition(":")
    host = host.strip("[]") if sep else "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"--http {text}: expected PORT or ADDR:PORT") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"--http {text}: port {number} outside 0..65535")
    return host or "127.0.0.1", number


class PageServer:
    def __init__(self, station: Station, db: str, options: PageOptions) -> None:
        self.station, self.options = station, options
        self.data = PageData(db, options.fake)
        self.bus = EventBus(PAGE_QUEUE)  # page messages, one bounded queue per open page
        self.db_name = str(db)
        self.url = ""
        self._runner: web.AppRunner | None = None
        self._tasks: list[asyncio.Task] = []
        self._dirty = False  # events since the last snapshot
        self._streams: set[Any] = set()
        self._stream_clients: Counter[str] = Counter()  # open event streams by client address
        self._tally = Tally(lambda text: station.emit(StationEvent(station.wall(), text)), time.monotonic)
        self._quiet = QuietLog(self._tally)
        self._hosts = HostCheck(options.host, options.hosts)  # and the addresses bound, at start
        self._gate: ConnectionGate | None = None
        self._listener: asyncio.AbstractServer | None = None
        self._recent: deque[dict] = deque(maxlen=RECENT_EVENTS)  # for a page that opens now
        self._cookie = f"btf_token_{options.port}"

    # -- start and stop ------------------------------------------------------------------------
    async def start(self, on_ready: Callable[[str], None] | None = None) -> str:
        """Serve; the page's address (without the token). OSError when the address is taken.
        `on_ready(url)` is called once its drawing worker has loaded (about a second later), so a page
        opened at the address it announces draws its first capture at once."""
        await self.data.refresh()  # every capture stored so far, before the first page asks
        app = web.Application(middlewares=[self._guard], client_max_size=64 * 1024)
        app.add_routes([
            web.get("/", self._index), web.get("/static/{name}", self._static), web.get("/events", self._events),
            web.get("/api/state", self._state), web.post("/api/command", self._command),
            web.get("/capture/{id:\\d+}/section", self._section),
            web.get("/capture/{id:\\d+}/{name:[a-z]+}.png", self._image),
            web.get("/api/btf", self._btf)])
        # a request whose page went away is cancelled: its drawing, if not begun, is not made
        self._runner = web.AppRunner(app, access_log=None, shutdown_timeout=1.0, handler_cancellation=True)
        await self._runner.setup()
        # Listening here rather than through a TCPSite: the gate is the protocol factory, so a
        # connection past the cap is closed before it holds a descriptor for long.
        self._gate = ConnectionGate(self._runner.server, connection_cap(), self._tally)
        self._listener = await asyncio.get_running_loop().create_server(
            self._gate, self.options.host, self.options.port, backlog=128)
        self._quiet.attach()
        bound = [sock.getsockname()[0] for sock in self._listener.sockets]
        self._hosts = HostCheck(self.options.host, [*self.options.hosts, *bound])
        host, port = self._listener.sockets[0].getsockname()[:2]
        self._cookie = f"btf_token_{port}"
        self.url = f"http://{host if ':' not in host else f'[{host}]'}:{port}/"
        self._tasks = [asyncio.ensure_future(self._follow()), asyncio.ensure_future(self._tick())]
        self.data.start_worker()
        if on_ready is not None:
            self._tasks.append(asyncio.ensure_future(self._announce(on_ready)))
        return self.url

    async def _announce(self, on_ready: Callable[[str], None]) -> None:
        await self.data.warm()
        on_ready(self.url)

    async def close(self) -> None:
        if self._listener is not None:
            self._listener.close()
        self._quiet.detach()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        for sub in list(self._streams):
            sub.close()  # each open page's stream ends
        if self._runner is not None:
            await self._runner.cleanup()
        await asyncio.get_running_loop().run_in_executor(None, self.data.close)

    # -- following the station -----------------------------------------------------------------
    async def _follow(self) -> None:
        sub = self.station.bus.subscribe(4096)
        try:
            while True:
                ev = (await sub.get()).to_json()  # as its declaration renders it (tools.station.events)
                kind = ev.get("kind")
                if kind in ("capture", "unchanged") and ev.get("stored") or kind == "lost":
                    cards = await self.data.refresh()
                    if cards:
                        self.bus.publish({"kind": "cards", "cards": cards})
                elif kind == "mask" and ev.get("stored"):
                    self.data.mask_arrived()
                    self.bus.publish({"kind": "rev", "rev": self.data.rev})
                if kind != "lost":
                    self._recent.append(ev)
                    self.bus.publish({"kind": "event", "event": ev})
                self._dirty = True
        finally:
            sub.close()

    async def _tick(self) -> None:
        """A snapshot after events (those within COALESCE_S as one), and every second anyway."""
        loop, last = asyncio.get_running_loop(), 0.0
        while True:
            await asyncio.sleep(COALESCE_S)
            self._tally.flush()
            if self._dirty or loop.time() - last >= SNAPSHOT_EVERY_S:
                self._dirty, last = False, loop.time()
                if self.bus.subscribers:
                    self.bus.publish({"kind": "snapshot", "snapshot": self.station.snapshot_json()})

    def hello(self, request: web.Request) -> dict:
        return {"kind": "hello", "snapshot": self.station.snapshot_json(), "cards": self.data.cards(),
                "rev": self.data.rev, "authorized": request["authorized"], "public": self.options.public,
                "db": self.db_name, "events": list(self._recent)}

    # -- security --------------------------------------------------------------------------------
    def _is_token(self, value: str | None) -> bool:
        return bool(value) and hmac.compare_digest(value.encode(), self.options.token.encode())

    @web.middleware
    async def _guard(self, request: web.Request, handler) -> web.StreamResponse:
        """Its headers are in: no deadline while it is served, the next request's due after."""
        self._gate.request_began(request.transport)
        try:
            why = self._hosts.refuses(request.headers.get("Host"))
            if why:
                self._tally.add("page: requests refused for their Host", why.split(" is not")[0])
                return _refused(403, why, plain=True, close=True)
            return await self._check(request, handler)
        finally:
            self._gate.request_ended(request.transport)

    async def _check(self, request: web.Request, handler) -> web.StreamResponse:
        if request.path.startswith("/static/"):
            return await handler(request)  # the page's code and style: no data in them
        if request.method == "GET" and request.path == "/" and "token" in request.query:
            if not self._is_token(request.query["token"]):
                return _refused(401, "wrong token: open the address the station printed at start-up", plain=True)
            resp = web.HTTPSeeOther("/")
            resp.set_cookie(self._cookie, self.options.token, httponly=True, samesite="Strict", path="/")
            return resp
        by_header = self._is_token(request.headers.get("X-BTF-Token"))
        by_cookie = self._is_token(request.cookies.get(self._cookie))
        request["authorized"] = by_header or by_cookie
        if request.method not in ("GET", "HEAD"):
            problem = self._refuse_change(request, by_header, by_cookie)
            if problem:
                return _refused(403, problem)
        elif not (request["authorized"] or self.options.public):
            return _refused(401, "this page needs the station's token: open the address the station printed "
                                 "at start-up (.../?token=...), or start the station with --http-public to "
                                 "let anyone on this address watch", plain=request.path == "/")
        return await handler(request)

    def _refuse_change(self, request: web.Request, by_header: bool, by_cookie: bool) -> str:
        """Why a state-changing request is refused ('' when it is not)."""
        if not (by_header or by_cookie):
            return "commands need the station's token (printed at its start-up)"
        origin = request.headers.get("Origin")
        own = f"{request.scheme}://{request.host}"
        if origin is not None and origin != own:
            return f"cross-site request refused: Origin {origin} is not this page's ({own})"
        if request.headers.get("Sec-Fetch-Site", "same-origin") not in ("same-origin", "none"):
            return "cross-site request refused"
        if origin is None and not by_header:  # a browser always says where a POST comes from
            return "a request with the token as a cookie must say its Origin"
        if request.content_type != "application/json":
            return "commands are JSON (Content-Type: application/json)"
        return ""

    # -- handlers --------------------------------------------------------------------------------
    async def _index(self, request: web.Request) -> web.Response:
        page = (static_dir() / "index.html").read_text(encoding="utf-8")
        page = page.replace("{{CSS}}", CSS).replace("{{FORMS}}", forms_html())
        page = page.replace("{{TITLE}}", _escape(f"btfscout station: {self.db_name}"))
        return web.Response(text=page, content_type="text/html", headers={"Cache-Control": "no-store"})

    async def _static(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in STATIC:
            raise web.HTTPNotFound()
        return web.Response(body=(static_dir() / name).read_bytes(), content_type=STATIC[name],
                            headers={"Cache-Control": "no-cache"})

    async def _state(self, request: web.Request) -> web.Response:
        return web.json_response(self.hello(request))

    def _too_many_streams(self, client: str) -> str:
        """Why one more event stream is refused ('' when it is not)."""
        if len(self._streams) >= STREAMS:
            return f"the page has {len(self._streams)} event streams open, its most: close a page elsewhere"
        if self._stream_clients[client] >= STREAMS_PER_CLIENT:
            return (f"{self._stream_clients[client]} event streams open from {client}, at most {STREAMS_PER_CLIENT}: "
                    "close another tab of this page")
        return ""

    async def _events(self, request: web.Request) -> web.StreamResponse:
        client = request.remote or "?"
        why = self._too_many_streams(client)
        if why:
            self._tally.add("page: event streams refused past their most", why)
            return _refused(503, why, close=True)
        resp = web.StreamResponse(headers={"Content-Type": "text/event-stream", "Cache-Control": "no-store"})
        sub = self.bus.subscribe()
        self._streams.add(sub)
        self._stream_clients[client] += 1
        try:
            await resp.prepare(request)
            await _send(resp, self.hello(request))
            while True:
                msg = await sub.get()
                await _send(resp, self.hello(request) if isinstance(msg, LostEvent) else msg)  # fell behind
        except (ConnectionError, EOFError):
            pass
        finally:
            self._streams.discard(sub)
            self._stream_clients[client] -= 1
            if not self._stream_clients[client]:
                del self._stream_clients[client]
            sub.close()
        return resp

    async def _command(self, request: web.Request) -> web.Response:
        try:
            body = await asyncio.wait_for(request.json(), BODY_TIMEOUT_S)
        except asyncio.TimeoutError:
            return _refused(408, f"the command's body did not arrive within {BODY_TIMEOUT_S:g} s", close=True)
        except ValueError as exc:
            return web.json_response({"error": str(exc).splitlines()[0]}, status=400)
        try:
            name, args = parse_form(body.get("name") if isinstance(body, dict) else None,
                                    body.get("fields", {}) if isinstance(body, dict) else None)
            cid, answer = self.station.submit(name, args)
        except (ValueError, RuntimeError) as exc:  # a bad form; a link holding too much already
            return web.json_response({"error": str(exc).splitlines()[0]}, status=400)
        try:
            got = await asyncio.wait_for(asyncio.shield(answer), ANSWER_WAIT_S)
        except asyncio.TimeoutError:
            return web.json_response({"command_id": cid, "waiting": True}, status=202)
        except asyncio.CancelledError:  # the station stopped before the robot answered
            return web.json_response({"command_id": cid, "error": "the station stopped"}, status=503)
        return web.json_response({"command_id": cid, "answer": got})

    async def _drawn(self, request: web.Request, what: str) -> dict:
        try:
            out = await self.data.drawn(int(request.match_info["id"]), what)
        except Exception as exc:  # a capture the worker cannot draw: said, never a traceback page
            raise web.HTTPInternalServerError(text=f"{type(exc).__name__}: {exc}".splitlines()[0]) from None
        if "missing" in out:
            raise web.HTTPNotFound(text=out["missing"])
        return out

    async def _section(self, request: web.Request) -> web.Response:
        return web.Response(text=(await self._drawn(request, "section"))["html"], content_type="text/html")

    async def _image(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        what = name if name in ("thumb", "histograms") else "section"  # drawings of their own
        out = await self._drawn(request, what)
        data = out["png"] if what != "section" else out["images"].get(name)
        if data is None:
            raise web.HTTPNotFound(text=f"capture {request.match_info['id']} has no {name} image")
        return web.Response(body=data, content_type="image/png", headers={"Cache-Control": "max-age=3600"})

    async def _btf(self, request: web.Request) -> web.Response:
        """The BTF panel's points, curve and leave-one-out figures (`tools.page.btf_panel`)."""
        status, body = await self.data.btf(request.query)
        return web.json_response(body, status=status)


async def _send(resp: web.StreamResponse, msg: dict) -> None:
    await resp.write(f"event: {msg['kind']}\ndata: {json.dumps(msg, separators=(',', ':'))}\n\n".encode())


def _refused(status: int, text: str, plain: bool = False, close: bool = False) -> web.Response:
    """A refusal: JSON for the page's requests, a line of text for a person at the address bar;
    `close`: the connection too (its descriptor freed at once)."""
    resp = web.Response(text=text + "\n", status=status) if plain else web.json_response({"error": text}, status=status)
    if close:
        resp.force_close()
    return resp


def _escape(text: str) -> str:
    import html

    return html.escape(text)
