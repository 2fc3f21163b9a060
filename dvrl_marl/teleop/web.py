"""The surgeon seat in a web browser: a Starlette app served by uvicorn, frames and inputs over one websocket.

``dvrl-marl teleop`` builds a :class:`~dvrl_marl.teleop.session.TeleopSession` and serves it with
:class:`TeleopServer`. The page (``static/index.html``) shows the endoscope view and the episode's status and sends
the person's keys and gamepad; the first page to connect drives the seat, later ones watch as spectators (one of
them may take the seat once it is free). Needs ``pip install "dvrl-marl[teleop]"``.

Safe by default: the server binds to 127.0.0.1; another interface needs ``allow_remote=True``
(``--allow-remote``). Every connection, page or websocket, must carry the access token (``?token=...``, in the URL
the server prints); a wrong one gets 403 / close code 1008. Messages from a page that are not JSON objects the
device understands, binary, or longer than :data:`MAX_MESSAGE_BYTES` are dropped and counted (the page shows the
count and the last reason); a message over :data:`MAX_WEBSOCKET_BYTES` closes that connection, never the server.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import secrets
import socket
import threading
from importlib import resources

from dvrl_marl.teleop.browser import BadMessage
from dvrl_marl.teleop.session import TeleopSession

__all__ = ["create_app", "TeleopServer", "MAX_MESSAGE_BYTES", "MAX_WEBSOCKET_BYTES", "is_loopback"]

#: A page's messages are tiny (a key, the sticks): longer ones are dropped and counted.
MAX_MESSAGE_BYTES = 4096
#: Longer than this, uvicorn closes the connection before the message is read into memory.
MAX_WEBSOCKET_BYTES = 1 << 20
_CONTROL = {"start": "begin", "reset": "reset"}
_POLICY_VIOLATION = 1008


def _require_web():
    try:
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as error:  # the optional extra
        raise ModuleNotFoundError('the web seat needs Starlette and uvicorn: pip install "dvrl-marl[teleop]"',
                                  name=error.name) from error


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _page(name: str) -> str:
    return resources.files("dvrl_marl.teleop").joinpath("static", name).read_text(encoding="utf-8")


class _Client:
    def __init__(self, websocket):
        self.websocket = websocket
        self.role = "spectator"
        self.wake = asyncio.Event()


class _Hub:
    """The pages connected to one session: who drives the seat, who watches, what was dropped."""

    def __init__(self, session: TeleopSession, token: str):
        self.session, self.token = session, token
        self.clients: list[_Client] = []
        self.controller: _Client | None = None
        self.loop: asyncio.AbstractEventLoop | None = None

    def token_ok(self, given) -> bool:
        return isinstance(given, str) and secrets.compare_digest(given.encode(), self.token.encode())

    def notify(self) -> None:
        """From the session's thread: a new frame is ready."""
        if self.loop is not None and not self.loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop closed between the test and the call
                self.loop.call_soon_threadsafe(self._wake_all)

    def _wake_all(self) -> None:
        for client in self.clients:
            client.wake.set()

    def _audience(self) -> None:
        self.session.audience.update(controller=self.controller is not None,
                                     spectators=sum(c.role == "spectator" for c in self.clients))

    def _drop(self, reason: str) -> None:
        self.session.audience["dropped_messages"] += 1
        self.session.audience["last_drop"] = reason[:200]

    async def _set_role(self, client: _Client, role: str) -> None:
        client.role = role
        if role == "controller":
            self.controller = client
            self.session.device.connect()
        self._audience()
        with contextlib.suppress(Exception):
            await client.websocket.send_text(json.dumps({"type": "role", "role": role}))

    async def websocket(self, websocket) -> None:
        if not self.token_ok(websocket.query_params.get("token")):
            await websocket.close(code=_POLICY_VIOLATION)
            return
        await websocket.accept()
        client = _Client(websocket)
        self.clients.append(client)
        await self._set_role(client, "controller" if self.controller is None else "spectator")
        sender = asyncio.create_task(self._send_frames(client))
        try:
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    break
                await self._receive(client, message)
        finally:
            sender.cancel()
            self.clients.remove(client)
            if self.controller is client:
                self.controller = None
                self.session.device.disconnect()
            self._audience()

    async def _send_frames(self, client: _Client) -> None:
        sent = -1
        with contextlib.suppress(Exception):  # the page went away: the receiving side cleans up
            while True:
                number, payload = self.session.latest()
                if number != sent and payload:
                    await client.websocket.send_bytes(payload)
                    sent = number
                await client.wake.wait()
                client.wake.clear()

    async def _receive(self, client: _Client, message: dict) -> None:
        text = message.get("text")
        if text is None:
            self._drop("binary messages are not accepted")
            return
        if len(text.encode()) > MAX_MESSAGE_BYTES:
            self._drop(f"message of {len(text.encode())} bytes (at most {MAX_MESSAGE_BYTES})")
            return
        try:
            data = json.loads(text)
        except (ValueError, RecursionError):  # a few kB of nested brackets exhaust the parser's recursion
            self._drop("not JSON (or nested too deeply)")
            return
        try:
            await self._act(client, data)
        except Exception as error:  # noqa: BLE001  (no message may end the connection: drop it, count it)
            self._drop(f"message not usable: {type(error).__name__}")

    async def _act(self, client: _Client, data) -> None:
        kind = data.get("type") if isinstance(data, dict) else None
        if kind == "take":
            if self.controller is None:
                await self._set_role(client, "controller")
            return
        if client is not self.controller:
            if kind != "ping":  # a spectator's page pings like any other: that is no dropped input
                self._drop("a spectator's input (only the page that drives the seat is heard)")
            return
        if kind in _CONTROL:
            getattr(self.session, _CONTROL[kind])()
        elif kind == "record":
            if not isinstance(data.get("on"), bool):
                self._drop("'record' needs \"on\": true or false")
            else:
                self.session.set_recording(data["on"])
        else:
            try:
                self.session.device.handle(data)
            except BadMessage as error:
                self._drop(str(error))


def create_app(session: TeleopSession, token: str):
    """The Starlette app serving ``session``: ``/`` (the page, its script inline), ``/status`` (JSON) and ``/ws``."""
    _require_web()
    from starlette.applications import Starlette
    from starlette.responses import HTMLResponse, JSONResponse, PlainTextResponse
    from starlette.routing import Route, WebSocketRoute

    hub = _Hub(session, token)
    # One response carries the page and its script: nothing to fetch without the token.
    page = _page("index.html").replace('<script src="teleop.js"></script>', f"<script>\n{_page('teleop.js')}</script>")
    refused = PlainTextResponse("403: missing or wrong access token; open the URL that `dvrl-marl teleop` printed",
                                status_code=403)

    def guarded(handler):
        async def endpoint(request):
            return handler(request) if hub.token_ok(request.query_params.get("token")) else refused
        return endpoint

    @contextlib.asynccontextmanager
    async def lifespan(app):
        hub.loop = asyncio.get_running_loop()
        session.subscribe(hub.notify)
        session.start()
        yield

    routes = [
        Route("/", guarded(lambda request: HTMLResponse(page))),
        Route("/status", guarded(lambda request: JSONResponse(session.status()))),
        WebSocketRoute("/ws", hub.websocket),
    ]
    app = Starlette(routes=routes, lifespan=lifespan)
    app.state.hub = hub
    return app


class TeleopServer:
    """Serves a session on ``host:port`` (``port=0``: any free port). :meth:`run` blocks (Ctrl-C stops it);
    :meth:`start` serves from a thread (tests, notebooks) until :meth:`stop`. Either way the session is closed at
    the end, which writes its recording."""

    def __init__(self, session: TeleopSession, host: str = "127.0.0.1", port: int = 8000, *,
                 allow_remote: bool = False, token: str | None = None):
        _require_web()
        if not is_loopback(host) and not allow_remote:
            raise ValueError(f"refusing to serve the seat on {host!r}: only this machine (127.0.0.1) can reach it "
                             "by default; pass allow_remote=True (--allow-remote) to serve other machines")
        if token is not None and len(token) < 16:
            raise ValueError("an access token must be at least 16 characters")
        self.session, self.host = session, host
        self.token = token or secrets.token_urlsafe(16)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._socket = socket.socket(family, socket.SOCK_STREAM)
        self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._socket.bind((host, int(port)))
        self.port = self._socket.getsockname()[1]
        # Listening from here on: a page opened as soon as the URL is printed waits in the backlog until the server
        # starts, instead of being refused (measured: refused under load between printing the URL and serving).
        self._socket.listen(128)
        import uvicorn

        self.app = create_app(session, self.token)
        self._server = uvicorn.Server(uvicorn.Config(self.app, log_level="warning", ws_max_size=MAX_WEBSOCKET_BYTES,
                                                     timeout_graceful_shutdown=2, lifespan="on"))
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "localhost") else self.host
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{self.port}/?token={self.token}"

    def run(self) -> list[dict]:
        """Serve until interrupted; returns the datasets the session wrote."""
        try:
            self._server.run(sockets=[self._socket])
        except KeyboardInterrupt:  # uvicorn shuts down gracefully on Ctrl-C, then re-raises it: that is our stop
            pass
        finally:
            saved = self.session.close()
        return saved

    def start(self, timeout: float = 30.0) -> "TeleopServer":
        self._thread = threading.Thread(target=self._server.run, kwargs={"sockets": [self._socket]},
                                        name="teleop-server", daemon=True)
        self._thread.start()
        for _ in range(int(timeout * 100)):
            if self._server.started:
                return self
            if not self._thread.is_alive():
                break
            threading.Event().wait(0.01)
        raise RuntimeError("the teleop server did not start")

    def stop(self, timeout: float = 30.0) -> list[dict]:
        self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout)
        return self.session.close()
