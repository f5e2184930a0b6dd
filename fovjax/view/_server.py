"""The viewer's web server (aiohttp): the page, its static files, and one WebSocket per client.

One renderer, one frame loop: while a client is connected, frames are rendered one after
another on a single worker thread, each for the newest gaze at its start, and sent to the
active client (the first connected; the others wait their turn and are told so). Latency over
throughput, never a queue: at most one frame is in flight to the page. The next frame is
rendered while the page shows the previous one; when it is done and the page has not
acknowledged the previous one yet, it waits at most one frame's time for that (still fresher
than a new frame would be), else it is dropped and the next one rendered. A page that stops
acknowledging for `ACK_TIMEOUT_S` gets one frame rendered per `ACK_TIMEOUT_S`.

Gaze-to-display latency: for the mouse, the page measures it on its own clock (mouse event ->
the animation frame that shows the first frame rendered from it) and reports it with the
acknowledgement; for a gaze source, the server measures sample time -> acknowledgement received
on the source's clock (this includes the acknowledgement's trip back, a fraction of a
millisecond on one machine).

Safety: bound to any address other than the loopback one, every request needs `?token=` (a
random token, printed in the URL); WebSocket upgrades from another origin are refused; every
page message is validated (`parse_message`) and an invalid one is logged and ignored.
"""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import contextlib
import hmac
import importlib.resources
import ipaddress
import json
import logging
import queue
import secrets
import statistics
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ._protocol import MAX_MESSAGE_BYTES, MessageError, parse_message

if TYPE_CHECKING:
    from ._renderer import RenderedFrame

log = logging.getLogger("fovjax.view")

ACK_TIMEOUT_S = 1.0
# aiohttp closes a WebSocket whose message exceeds this; smaller oversize messages reach
# `parse_message`, which ignores them with a reason.
WS_MAX_MESSAGE_BYTES = 64 * MAX_MESSAGE_BYTES
LATENCY_WINDOW = 60
STATIC_FILES = {"viewer.js": "application/javascript", "viewer.css": "text/css"}


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _static(name: str) -> bytes:
    return importlib.resources.files(__package__ or "fovjax.view").joinpath("static", name).read_bytes()


class RenderThread(concurrent.futures.Executor):
    """One daemon worker thread (the renderer is single-threaded): unlike a ThreadPoolExecutor's
    worker, it does not hold up the interpreter's exit on Ctrl-C while a program compiles."""

    def __init__(self, name: str = "fovjax-view-render"):
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self.busy = False  # running a task now (a frame or a compile)
        self._thread = threading.Thread(target=self._work, name=name, daemon=True)
        self._thread.start()

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            future, fn, args, kwargs = item
            if not future.set_running_or_notify_cancel():
                continue
            self.busy = True
            try:
                future.set_result(fn(*args, **kwargs))
            except BaseException as err:  # handed to the waiting coroutine
                future.set_exception(err)
            finally:
                self.busy = False

    def submit(self, fn, /, *args, **kwargs):
        future = concurrent.futures.Future()
        self._queue.put((future, fn, args, kwargs))
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._queue.put(None)
        if wait:
            self._thread.join()


class _Client:
    def __init__(self, ws, peer: str):
        self.ws = ws
        self.peer = peer
        self.awaiting: int | None = None  # frame number sent and not yet acknowledged
        self.sent_at = 0.0
        self.acked = asyncio.Event()
        self.acked.set()


class Viewer:
    """The server around a `LiveRenderer`. `host`/`port`: where to listen (port 0: any free
    port; `url` says which after `start`); `token`: required in every URL (None: none, allowed
    on a loopback address only; default: a random one off loopback); `save_dir`: where "save"
    writes; `on_save`: called with the paths of each completed save (on the render thread).
    `saved`: the paths saved so far. `stop` lets a save in progress finish."""

    PAGE = "index.html"  # the page at /, and the files under /static/ (name -> content type)
    STATIC_FILES = STATIC_FILES

    def __init__(
        self, renderer, *, host="127.0.0.1", port=8000, token="auto", save_dir="fovjax-view", on_save=None
    ):
        if token == "auto":
            token = None if is_loopback(host) else secrets.token_urlsafe(16)
        if token is None and not is_loopback(host):
            raise ValueError(f"Viewer: binding to {host!r} (not loopback) needs a token")
        self.renderer = renderer
        self.host, self.port, self.token = host, port, token
        self.save_dir = Path(save_dir)
        self.on_save = on_save
        self.saved: list[Path] = []
        self._saving: concurrent.futures.Future | None = None
        self.clients: list[_Client] = []
        self.latencies_ms: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self.displayed = 0
        self.dropped_frames = 0
        self.ignored_messages = 0
        self.state = "starting"
        self._wake = asyncio.Event()
        self._executor = RenderThread()
        self._runner = None
        self._tasks: list[asyncio.Task] = []
        self._sent: dict[int, RenderedFrame] = {}
        self._shown_times: collections.deque = collections.deque(maxlen=30)

    # ---- HTTP ----------------------------------------------------------------------------------

    def _authorised(self, request) -> bool:
        if self.token is None:
            return True
        given = request.query.get("token", "")
        return hmac.compare_digest(given.encode(), self.token.encode())

    async def _index(self, request):
        from aiohttp import web

        if not self._authorised(request):
            return web.Response(status=403, text="fovjax view: a valid ?token= is required\n")
        html = _static(self.PAGE).decode()
        return web.Response(text=html, content_type="text/html", headers={"Cache-Control": "no-store"})

    async def _static_file(self, request):
        from aiohttp import web

        name = request.match_info["name"]
        if name not in self.STATIC_FILES:
            raise web.HTTPNotFound()
        return web.Response(body=_static(name), content_type=self.STATIC_FILES[name])

    def _same_origin(self, request) -> bool:
        origin = request.headers.get("Origin")
        if origin is None:  # not a browser (a script or a test client)
            return True
        return origin in (f"http://{request.host}", f"https://{request.host}")

    async def _websocket(self, request):
        from aiohttp import WSMsgType, web

        if not self._authorised(request):
            return web.Response(status=403, text="fovjax view: a valid ?token= is required\n")
        if not self._same_origin(request):
            log.warning("refused a WebSocket from origin %s", request.headers.get("Origin"))
            return web.Response(status=403, text="fovjax view: cross-origin WebSocket refused\n")
        ws = web.WebSocketResponse(max_msg_size=WS_MAX_MESSAGE_BYTES, heartbeat=30.0)
        await ws.prepare(request)
        client = _Client(ws, request.remote or "?")
        self.clients.append(client)
        log.info("client %s connected (%d connected)", client.peer, len(self.clients))
        await self._announce()
        self._wake.set()
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    await self._on_message(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self._ignore(client, f"binary message of {len(msg.data)} bytes (expected JSON text)")
                elif msg.type == WSMsgType.ERROR:
                    log.warning("client %s: connection error: %s", client.peer, ws.exception())
        finally:
            self.clients.remove(client)
            client.acked.set()
            log.info(
                "client %s disconnected (close code %s; %d connected)",
                client.peer,
                ws.close_code,
                len(self.clients),
            )
            with contextlib.suppress(Exception):
                await self._announce()
            self._wake.set()
        return ws

    def _ignore(self, client, reason: str) -> None:
        self.ignored_messages += 1
        log.warning("ignored a message from %s: %s", client.peer, reason)

    async def _on_message(self, client, data) -> None:
        try:
            msg = parse_message(data)
        except MessageError as err:
            self._ignore(client, str(err))
            return
        kind = msg["type"]
        if kind == "shown":
            self._on_shown(client, msg)
            return
        if not self.clients or client is not self.clients[0]:
            self._ignore(client, f"{kind} message from a client waiting its turn")
            return
        if kind == "gaze":
            if self.renderer.gaze_source is not None:
                self._ignore(client, f"mouse gaze while the gaze comes from {self.renderer.gaze_spec}")
                return
            self.renderer.set_mouse(msg["eye"], msg["x"], msg["y"], msg["t"])
        elif kind == "leave":
            self.renderer.mouse_left()
        elif msg["action"] == "save":
            await self._save(client)
        else:
            change = self.renderer.apply_action(msg["action"])
            log.info("%s: %s", msg["action"], change)
            await self._send_json(client, {"type": "status", "state": self.state, "message": change})

    def _on_shown(self, client, msg) -> None:
        if client.awaiting is None or msg["frame"] != client.awaiting:
            self._ignore(
                client, f"shown message for frame {msg['frame']}, not the frame awaited ({client.awaiting})"
            )
            return
        frame = self._sent.pop(msg["frame"], None)
        client.awaiting = None
        client.acked.set()
        self.displayed += 1
        self._shown_times.append(time.perf_counter())
        if frame is None or not frame.gaze_new:
            return
        if frame.gaze_t is not None and msg["latency_ms"] is not None:
            self.latencies_ms.append(msg["latency_ms"])
        elif frame.gaze_timestamp is not None:
            clock = self.renderer.gaze_source.clock
            self.latencies_ms.append((clock() - frame.gaze_timestamp) * 1e3)

    def _save_now(self, extra: dict) -> list[Path]:
        """On the render thread: save, and note the paths once every file is complete."""
        paths = self.renderer.save(self.save_dir, extra)
        self.saved.extend(paths)
        if self.on_save is not None:
            self.on_save(paths)
        return paths

    async def _save(self, client) -> None:
        self._saving = self._executor.submit(self._save_now, {"latency": self.latency_summary()})
        try:
            paths = await asyncio.wrap_future(self._saving)
        except (ValueError, OSError) as err:
            log.warning("save failed: %s", err)
            await self._send_json(
                client, {"type": "status", "state": self.state, "message": f"save failed: {err}"}
            )
            return
        log.info("saved %s", ", ".join(str(p) for p in paths))
        await self._send_json(client, {"type": "saved", "paths": [str(p.resolve()) for p in paths]})

    async def _send_json(self, client, payload) -> None:
        if not client.ws.closed:
            with contextlib.suppress(ConnectionError, RuntimeError):
                await client.ws.send_str(json.dumps(payload, allow_nan=False))

    async def _announce(self) -> None:
        for position, client in enumerate(self.clients):
            state = self.state if position == 0 else "waiting"
            message = (
                "" if position == 0 else f"another client is being served; you are number {position} in line"
            )
            await self._send_json(client, {"type": "status", "state": state, "message": message})

    def latency_summary(self) -> dict:
        values = list(self.latencies_ms)
        if not values:
            return {"last_ms": None, "median_ms": None, "count": 0}
        return {"last_ms": values[-1], "median_ms": statistics.median(values), "count": len(values)}

    def _fps(self) -> float | None:
        times = self._shown_times
        if len(times) < 2 or times[-1] == times[0]:
            return None
        return (len(times) - 1) / (times[-1] - times[0])

    # ---- the frame loop ------------------------------------------------------------------------

    def _has_work(self) -> bool:
        """Whether the active client has a frame to render (the 2D page always has; a subclass
        may wait for its input, setting `_wake` when it comes)."""
        return True

    def _ack_grace(self, frame) -> float:
        """How long a rendered frame waits for the page to show the previous one (seconds)."""
        return min(ACK_TIMEOUT_S, frame.stats["ms"]["frame"] / 1e3)

    async def _frame_loop(self) -> None:
        loop = asyncio.get_running_loop()
        self.state = "compiling"
        await self._announce()
        try:
            await loop.run_in_executor(self._executor, self.renderer.open)
            seconds = await loop.run_in_executor(self._executor, self.renderer.warmup)
        except Exception as err:  # the page must hear why nothing will come
            self.state = "error"
            log.info("could not start rendering: %s", err)  # raised to whoever awaits `frame_loop`
            for client in self.clients:
                await self._send_json(client, {"type": "status", "state": "error", "message": str(err)})
            raise
        log.info("compiled in %.1f s", seconds)
        self.state = "running"
        await self._announce()
        while True:
            if not self.clients or not self._has_work():
                self._wake.clear()
                await self._wake.wait()
                continue
            client = self.clients[0]
            if not client.acked.is_set() and time.perf_counter() - client.sent_at > ACK_TIMEOUT_S:
                # A page that stopped acknowledging (a background tab) costs one frame a second.
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(client.acked.wait(), ACK_TIMEOUT_S)
            try:
                frame = await loop.run_in_executor(self._executor, self.renderer.render_next)
            except Exception as err:
                # A failed frame (e.g. a configuration that cannot compile) is reported, the loop goes on.
                log.error("frame failed: %s: %s", type(err).__name__, err)
                await self._send_json(
                    client, {"type": "status", "state": "error", "message": f"frame failed: {err}"}
                )
                await asyncio.sleep(0.5)
                continue
            if not self.clients or self.clients[0] is not client or client.ws.closed:
                continue  # the client left while it rendered
            if client.awaiting is not None:
                # The page has not shown the previous frame yet. If it does within one frame's
                # time, this frame is still fresher than a new one would be; otherwise it is
                # dropped (never queued) and the next one rendered for the newest gaze.
                grace = self._ack_grace(frame)
                try:
                    await asyncio.wait_for(client.acked.wait(), grace)
                except TimeoutError:
                    self.dropped_frames += 1
                    continue
                if not self.clients or self.clients[0] is not client or client.ws.closed:
                    continue
            await self._send_frame(client, frame)

    async def _send_frame(self, client, frame) -> None:
        stats = dict(frame.stats)
        stats.update(
            type="frame",
            gaze_t=frame.gaze_t,
            latency=self.latency_summary(),
            fps=self._fps(),
            dropped_frames=self.dropped_frames,
            ignored_messages=self.ignored_messages,
            clients=len(self.clients),
        )
        client.awaiting = frame.number
        client.acked.clear()
        client.sent_at = time.perf_counter()
        self._sent = {frame.number: frame}
        try:
            await client.ws.send_str(json.dumps(stats, allow_nan=False))
            await client.ws.send_bytes(frame.jpeg)
        except (ConnectionError, RuntimeError) as err:
            log.info("client %s: send failed (%s)", client.peer, err)
            client.awaiting = None
            client.acked.set()

    # ---- life cycle ----------------------------------------------------------------------------

    def app(self):
        from aiohttp import web

        app = web.Application(client_max_size=WS_MAX_MESSAGE_BYTES)
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static_file)
        app.router.add_get("/ws", self._websocket)
        return app

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        query = f"?token={self.token}" if self.token else ""
        return f"http://{host}:{self.port}/{query}"

    async def start(self) -> str:
        """Start listening and the frame loop; returns the URL."""
        from aiohttp import web

        self._runner = web.AppRunner(self.app(), handle_signals=False, access_log=None)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        await site.start()
        if self.port == 0:
            self.port = self._runner.addresses[0][1]
        self._tasks.append(asyncio.create_task(self._frame_loop(), name="fovjax-view-frames"))
        return self.url

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for client in list(self.clients):
            with contextlib.suppress(Exception):
                await client.ws.close()
        if self._runner is not None:
            await self._runner.cleanup()
        saving = self._saving
        if saving is not None and not saving.cancel():
            # A save already running (quick: one PNG and its statistics) is finished, never cut.
            with contextlib.suppress(Exception):
                await asyncio.wrap_future(saving)
        # Not through the render thread: it may be in the middle of a compile.
        with contextlib.suppress(Exception):
            self.renderer.close()
        self._executor.shutdown(wait=False)

    def join_render_thread(self) -> None:
        """After `stop`: wait until the render thread has finished its task and ended."""
        self._executor.shutdown(wait=True)

    @property
    def render_busy(self) -> bool:
        """Whether the render thread is inside a task now (a frame, a compile)."""
        return self._executor.busy

    @property
    def frame_loop(self) -> asyncio.Task | None:
        return self._tasks[0] if self._tasks else None
