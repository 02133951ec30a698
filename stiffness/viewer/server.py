"""The live server: a loopback-only web server process, its client, and meshcat's window.

The live viewer starts its own server process (:func:`_serve`: meshcat's viewer page,
websocket and ZeroMQ command socket) bound to 127.0.0.1 by default, on free ports, with
``python -m stiffness.viewer --serve HOST PORT PARENT_PID [LOG]``. Every request to it has a
timeout (nothing waits for a browser forever), and the process is stopped by
:meth:`LiveServer.close`, at interpreter exit, and by itself when its parent process dies.
meshcat 0.3.2's own server binds its web port on every interface and its ``wait`` can leave its
command socket stuck; neither is used.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stiffness.errors import StiffnessError
from stiffness.viewer.deps import meshcat_modules
from stiffness.viewer.page import render_page
from stiffness.viewer.scene import SceneStore

if TYPE_CHECKING:
    import zmq

#: Address the live server binds by default (loopback only).
LOOPBACK = "127.0.0.1"
#: Seconds the client waits for any answer of the live server.
DEFAULT_TIMEOUT = 10.0


@dataclass(frozen=True)
class ServerLimits:
    """Bounds that keep the live server's memory, descriptors and latency bounded.

    Attributes
    ----------
    idle_timeout_s
        Seconds a connection may stay idle or take to send its request headers (slowloris
        defence) or its body before the server closes it.
    max_connections
        Open connections (pages' websockets included). A new connection beyond it evicts the
        oldest connection that is not a page (an idle keep-alive or a slowloris half request),
        so a held-open flood cannot lock well-behaved clients out. The listening socket's
        accept queue holds as many (the kernel's ``somaxconn`` caps it): with Tornado's
        default of 128, a burst of connections while the server waits for the CPU filled the
        queue, and a well-behaved client's connection waited a second for its SYN retry.
    max_websockets
        Connected pages beyond which a new websocket is refused (HTTP 503).
    max_pending_bytes
        Bytes queued for one page that it has not read; a page over it (a client that never
        reads) is disconnected, so a stalled client cannot grow the server's memory.
    max_message_bytes
        Largest websocket message accepted from a page (its controls are a few hundred bytes).
    max_header_bytes, max_body_bytes
        Largest HTTP request header block and body.
    ping_interval_s
        Seconds between websocket pings; a page that does not answer within one interval is
        dropped.
    """

    idle_timeout_s: float = 10.0
    max_connections: int = 512
    max_websockets: int = 128
    max_pending_bytes: int = 64 * 2**20
    max_message_bytes: int = 64 * 2**10
    max_header_bytes: int = 16 * 2**10
    max_body_bytes: int = 64 * 2**10
    ping_interval_s: float = 10.0


class RecordingWindow:
    """meshcat's window protocol: records every command, forwards it to a live server if any."""

    def __init__(self, server: LiveServer | None = None) -> None:
        self.scene = SceneStore()
        self.server = server
        self.web_url = server.web_url if server is not None else None

    def send(self, command: Any) -> None:
        data = command.lower()
        packed = meshcat_modules().msgpack.packb(data)
        self.scene.apply(data["type"], data["path"], packed, data.get("property"))
        if self.server is not None:
            self.server.request([data["type"].encode(), data["path"].encode(), packed])

    def get_scene(self) -> str:
        return render_page(self.scene.commands(), None, "meshcat")

    def get_image(self) -> Any:
        raise StiffnessError("image capture is not supported; use export() and a browser")

    def close(self) -> None:
        if self.server is not None:
            self.server.close()


class LiveServer:
    """The viewer's web server, in its own process, bound to ``host`` (loopback by default).

    Serves the viewer page at ``web_url``, meshcat's scripts under ``/static/``, the scene over
    a websocket at ``/websocket``, and takes commands on a ZeroMQ socket (``zmq_url``). Every
    request times out after ``timeout`` s; the process stops on :meth:`close`, at interpreter
    exit, or when this process dies.

    Parameters
    ----------
    host
        Address to bind (default 127.0.0.1: unreachable from other machines).
    port
        Web port (0: a free port).
    timeout
        Seconds to wait for the process to start and for each answer.
    limits
        Bounds on connections, queued bytes and timeouts (:class:`ServerLimits`).
    """

    def __init__(self, host: str = LOOPBACK, port: int = 0, timeout: float = DEFAULT_TIMEOUT,
                 limits: ServerLimits | None = None) -> None:
        import zmq

        self.host, self.timeout = host, float(timeout)
        self.limits = limits or ServerLimits()
        self._lock = threading.RLock()
        log, self._log_path = tempfile.mkstemp(prefix="stiffness-viewer-", suffix=".log")
        command = [sys.executable, "-m", "stiffness.viewer", "--serve", host, str(int(port)),
                   str(os.getpid()), self._log_path, json.dumps(asdict(self.limits))]
        try:
            # own session: a Ctrl-C in a notebook cell does not kill the server
            self.process = subprocess.Popen(
                command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log,
                start_new_session=True, text=True,
            )
        finally:
            os.close(log)
        self._closed = False
        atexit.register(self.close)
        urls = self._read_urls()
        self.zmq_url, self.web_url = urls["zmq_url"], urls["web_url"]
        threading.Thread(target=self._drain, daemon=True).start()
        self._context = zmq.Context()
        self._socket = self._command_socket()

    def _read_urls(self) -> dict:
        found: dict = {}
        lines: list[str] = []

        stdout = self.process.stdout
        assert stdout is not None  # opened with stdout=PIPE

        def reader() -> None:
            for line in stdout:
                lines.append(line.strip())
                if line.startswith("web_url="):
                    return

        thread = threading.Thread(target=reader, daemon=True)
        thread.start()
        thread.join(self.timeout)
        for line in lines:
            if "=" in line:
                key, value = line.split("=", 1)
                found[key] = value
        if "zmq_url" not in found or "web_url" not in found:
            log = self._log_tail()
            code = self.process.poll()
            why = f"exited with code {code}" if code is not None else \
                f"did not start within {self.timeout:g} s"
            self.close()
            raise StiffnessError(f"the viewer's server {why} (its log: {log})")
        return found

    def _drain(self) -> None:
        stdout = self.process.stdout
        assert stdout is not None  # opened with stdout=PIPE
        try:
            for _ in stdout:
                pass
        except (OSError, ValueError):
            pass

    def _log_tail(self) -> str:
        try:
            return Path(self._log_path).read_text()[-600:].strip() or "empty"
        except OSError:
            return "unreadable"

    def _command_socket(self) -> zmq.Socket:
        """A new REQ socket connected to the server's command socket."""
        import zmq

        socket = self._context.socket(zmq.REQ)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.SNDTIMEO, int(self.timeout * 1000))
        socket.connect(self.zmq_url)
        return socket

    def _connect(self) -> None:
        """Replace the command socket (a REQ socket left waiting cannot send again)."""
        self._socket.close(linger=0)
        self._socket = self._command_socket()

    def request(self, frames: list[bytes], timeout: float | None = None) -> bytes:
        """Send one command, return the server's answer.

        Raises
        ------
        StiffnessError
            If the server is closed or does not answer within ``timeout`` s (default: the
            server's); the command socket is then reset so later requests still work.
        """
        import zmq

        timeout = self.timeout if timeout is None else timeout
        with self._lock:
            if self._closed:
                raise StiffnessError("the viewer's server is closed")
            try:
                self._socket.send_multipart(frames)
                if self._socket.poll(int(timeout * 1000), zmq.POLLIN):
                    return self._socket.recv()
            except zmq.ZMQError as exc:
                self._connect()
                raise StiffnessError(f"the viewer's server failed: {exc}") from exc
            self._connect()
            alive = "running" if self.process.poll() is None else "exited"
            raise StiffnessError(
                f"the viewer's server ({alive}) did not answer within {timeout:g} s"
            )

    def clients(self) -> int:
        """Number of browsers connected."""
        return int(self.request([b"clients"]))

    def events(self) -> list[dict]:
        """Control changes sent by the pages since the last call, oldest first."""
        return json.loads(self.request([b"events"]))

    def set_overlay(self, overlay: dict) -> None:
        """Send the legend and controls to the server (and its pages)."""
        self.request([b"overlay", json.dumps(overlay).encode()])

    def wait_for_browser(self, timeout: float = 10.0, poll: float = 0.1) -> bool:
        """Wait at most ``timeout`` s for a browser to connect; whether one did."""
        deadline = time.monotonic() + timeout
        while True:
            if self.clients() > 0:
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(poll)

    @property
    def running(self) -> bool:
        """Whether the server process is alive."""
        return self.process.poll() is None

    def close(self) -> None:
        """Stop the server process (idempotent)."""
        with self._lock:
            if self._closed:
                return
            if getattr(self, "_socket", None) is not None:
                with contextlib.suppress(StiffnessError):
                    self.request([b"stop"], timeout=1.0)
            self._closed = True
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(timeout=2.0)
            if self.process.poll() is None:
                self.process.terminate()
                try:
                    self.process.wait(timeout=3.0)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait(timeout=3.0)
            if self.process.stdout is not None:
                self.process.stdout.close()
            if getattr(self, "_socket", None) is not None:
                self._socket.close(linger=0)
                self._context.term()
            with contextlib.suppress(OSError):
                os.unlink(self._log_path)
            atexit.unregister(self.close)

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _serve(host: str, port: int, parent_pid: int, log_path: str | None = None,
           limits: ServerLimits | None = None) -> int:
    """The server process: meshcat's page scripts, our page, a websocket and a ZeroMQ socket.

    Stops on the ``stop`` command, on SIGTERM, or when ``parent_pid`` is no longer its parent
    (the owner died without closing it; it then removes its log file ``log_path``). Every
    connection is bounded by ``limits`` (:class:`ServerLimits`).
    """
    bounds = limits or ServerLimits()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import tornado.ioloop
        import zmq
        from zmq.eventloop.zmqstream import ZMQStream

    store = SceneStore()
    state: dict = {"overlay": None, "events": [], "pool": set()}
    loop = tornado.ioloop.IOLoop.current()
    server, web_port, broadcast = _web_server(host, port, store, state, bounds)

    context = zmq.Context()
    rep = context.socket(zmq.REP)
    rep.setsockopt(zmq.LINGER, 0)
    rep.bind(f"tcp://{host}:*")
    zmq_url = rep.getsockopt_string(zmq.LAST_ENDPOINT)
    stream = ZMQStream(rep)

    def stop() -> None:
        server.stop()
        loop.stop()

    shown_host = f"[{host}]" if ":" in host else host
    web_url = f"http://{shown_host}:{web_port}/"
    stream.on_recv(_command_handler(store, state, broadcast, stream.send, web_url,
                                    lambda: loop.add_callback(stop)))

    def watch_parent() -> None:
        if os.getppid() != parent_pid:
            if log_path:
                with contextlib.suppress(OSError):
                    os.unlink(log_path)
            stop()

    tornado.ioloop.PeriodicCallback(watch_parent, 1000).start()
    print(f"zmq_url={zmq_url}", flush=True)
    print(f"web_url={web_url}", flush=True)
    try:
        loop.start()
    except KeyboardInterrupt:
        pass
    finally:
        stream.close()
        context.term()
    return 0


def main(argv: list[str]) -> int:
    """``python -m stiffness.viewer --serve HOST PORT PARENT_PID [LOG [LIMITS_JSON]]``."""
    if len(argv) in (4, 5, 6) and argv[0] == "--serve":
        limits = ServerLimits(**json.loads(argv[5])) if len(argv) == 6 else None
        return _serve(argv[1], int(argv[2]), int(argv[3]), argv[4] if len(argv) >= 5 else None,
                      limits)
    print("usage: python -m stiffness.viewer --serve HOST PORT PARENT_PID [LOG [LIMITS_JSON]] "
          "(started by StiffnessViewer; use `stiffness view`)", file=sys.stderr)
    return 2


def _web_server(host: str, port: int, store: SceneStore, state: dict, bounds: ServerLimits
                ) -> tuple[Any, int, Callable[[bytes | str, bool], None]]:
    """The web server of :func:`_serve`, listening on ``host`` (``port`` 0: a free one): our
    page, meshcat's scripts and the websocket that replays ``store`` to each page. Returns the
    server, its port and the function that sends a message to every page."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import tornado.httpserver
        import tornado.netutil
        import tornado.web
        import tornado.websocket
        from meshcat.servers.zmqserver import VIEWER_ROOT, StaticFileHandlerNoCache

    class Page(tornado.web.RequestHandler):
        def get(self) -> None:
            self.set_header("Cache-Control", "no-store")
            self.write(render_page([], state["overlay"], "stiffness viewer", live=True))

    class Socket(tornado.websocket.WebSocketHandler):
        pending = 0  # bytes queued for this page and not yet written to its socket

        def prepare(self) -> None:
            if len(state["pool"]) >= bounds.max_websockets:
                self.set_status(503)
                self.finish("too many viewer pages are connected")

        def open(self) -> None:  # noqa: A003 (tornado's name)
            state["pool"].add(self)
            for packed in store.commands():
                send(self, packed, True)
            if state["overlay"] is not None:
                send(self, json.dumps({"type": "overlay", "data": state["overlay"]}), False)

        def on_message(self, message: str | bytes) -> None:
            try:
                data = json.loads(message)
            except (TypeError, ValueError):
                return
            if isinstance(data, dict) and data.get("type") == "control":
                state["events"] = (state["events"] + [data.get("state", {})])[-100:]

        def on_close(self) -> None:
            state["pool"].discard(self)

    def send(socket: Socket, message: bytes | str, binary: bool) -> None:
        """Queue ``message`` for one page; drop the page if it stopped reading."""
        size = len(message)
        if socket.pending + size > bounds.max_pending_bytes:
            state["pool"].discard(socket)
            socket.close(1008, "not reading")
            return
        try:
            written = socket.write_message(message, binary=binary)
        except tornado.websocket.WebSocketClosedError:
            state["pool"].discard(socket)
            return
        socket.pending += size

        def done(future: Any) -> None:
            socket.pending -= size
            if not future.cancelled():
                future.exception()  # a page that left: its write fails, nothing to report

        written.add_done_callback(done)

    def broadcast(message: bytes | str, binary: bool) -> None:
        for socket in list(state["pool"]):
            send(socket, message, binary)

    BoundedHTTPServer = _bounded_http_server(state, bounds)

    app = tornado.web.Application([
        (r"/", Page),
        (r"/websocket", Socket),
        (r"/static/(.*)", StaticFileHandlerNoCache, {"path": VIEWER_ROOT}),
    ], websocket_max_message_size=bounds.max_message_bytes,
        websocket_ping_interval=bounds.ping_interval_s,
        websocket_ping_timeout=bounds.ping_interval_s)
    sockets = tornado.netutil.bind_sockets(
        port, address=host, backlog=max(128, bounds.max_connections))
    server = BoundedHTTPServer(
        app, idle_connection_timeout=bounds.idle_timeout_s, body_timeout=bounds.idle_timeout_s,
        max_header_size=bounds.max_header_bytes, max_body_size=bounds.max_body_bytes)
    server.add_sockets(sockets)
    web_port = sockets[0].getsockname()[1]

    return server, web_port, broadcast


def _bounded_http_server(state: dict, bounds: ServerLimits) -> type:
    """tornado's HTTP server keeping at most ``bounds.max_connections`` connections open (a
    new one evicts the oldest that is not a page's websocket, ``state["pool"]``)."""
    import tornado.httpserver

    class BoundedHTTPServer(tornado.httpserver.HTTPServer):
        """At most ``bounds.max_connections`` open: a new one evicts the oldest non-page one."""

        streams: collections.OrderedDict = collections.OrderedDict()

        def handle_stream(self, stream, address) -> None:  # noqa: ANN001 (tornado's types)
            streams = self.streams
            for old in [s for s in streams if s.closed()]:
                del streams[old]
            if len(streams) >= bounds.max_connections:
                pages = {page.ws_connection.stream for page in state["pool"]
                         if page.ws_connection is not None}
                victim = next((s for s in streams if s not in pages), None)
                if victim is None:
                    stream.close()
                    return
                del streams[victim]
                victim.close()
            streams[stream] = None
            super().handle_stream(stream, address)

    return BoundedHTTPServer


def _command_handler(store: SceneStore, state: dict,
                     broadcast: Callable[[bytes | str, bool], None],
                     reply_to: Callable[[bytes], object], web_url: str,
                     request_stop: Callable[[], object]) -> Callable[[list[bytes]], None]:
    """What :func:`_serve` does with each command on its ZeroMQ socket (``frames``: the command,
    then its arguments): record and broadcast scene commands, keep the overlay, answer queries
    (pages connected, control events, the page's URL), stop; every command is answered."""

    def handle(frames: list[bytes]) -> None:
        kind = frames[0].decode()
        reply = b"ok"
        if kind in ("set_object", "set_transform", "set_property", "set_animation", "delete"):
            if len(frames) != 3:
                reply = b"error: expected 3 frames"
            else:
                key = None
                if kind == "set_property":
                    key = meshcat_modules().msgpack.unpackb(frames[2]).get("property")
                store.apply(kind, frames[1].decode(), frames[2], key)
                broadcast(frames[2], True)
        elif kind == "overlay":
            state["overlay"] = json.loads(frames[1])
            broadcast(json.dumps({"type": "overlay", "data": state["overlay"]}), False)
        elif kind == "clients":
            reply = str(len(state["pool"])).encode()
        elif kind == "events":
            reply = json.dumps(state["events"]).encode()
            state["events"] = []
        elif kind == "url":
            reply = web_url.encode()
        elif kind == "stop":
            request_stop()
        else:
            reply = b"error: unknown command " + frames[0]
        reply_to(reply)

    return handle
