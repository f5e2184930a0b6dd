"""The study player's web server (`fovjax view --study`): a page that runs one test of the
thesis's user study with a participant -- form, instructions, the trials' sequences with their
black gaps, the answer buttons -- and hands every answer to the study as it is given.

The stimuli are pre-rendered clips (JPEG frames, stereo side by side), loaded and decoded by the
page before the test starts, so what is on screen at any moment depends only on the page's
`requestAnimationFrame` clock, never on rendering or the network. The page draws each segment
of a trial for its protocol duration, rounded to the nearest display frame, and reports when it
first drew each one (requestAnimationFrame timestamps) with the answer.

`study` is the object that knows the protocol and keeps the record (`fovjax.cli._view_study`
builds it from `fovjax.eval.StudyLog`); the server only moves JSON between it and the page:

- ``study.state() -> dict``: participant, test, trials, next trial, whether the form is needed;
- ``study.trial(index) -> dict``: what trial `index` shows (segments with their clip and
  seconds), its question and answer choices;
- ``study.save_form(form: dict) -> dict`` and ``study.record(payload: dict) -> dict``: store the
  form / an answer, raising ValueError (the page shows the message) when it is not acceptable.

Routes: ``/`` the page, ``/static/NAME``, ``/api/state``, ``/api/trial/N``, ``POST /api/form``,
``POST /api/answer``, ``/clip/C/F.jpg`` (frame F of clip C). As the live viewer: bound to any
address other than loopback every request needs `?token=`, and a POST from another origin is
refused.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import secrets

from ._server import _static, is_loopback

log = logging.getLogger("fovjax.view")

STUDY_STATIC_FILES = {"study.js": "application/javascript", "study.css": "text/css"}
MAX_ANSWER_BYTES = 1 << 20  # an answer with every frame's timing of a long slider session


class StudyServer:
    """Serve `study` (see the module docstring) with its `clips`: a list of (name, [JPEG bytes
    per frame]) played at `clip_fps`, frames ping-ponged so a loop never jumps; `fixation`: the
    normalised point of each eye's display the participant looks at (where the clips' fovea
    is), marked on the page. `done` is set once the study reports that every trial is answered."""

    def __init__(self, study, clips, *, clip_fps: float, fixation=(0.5, 0.5), host="127.0.0.1", port=8000):
        if not clips:
            raise ValueError("StudyServer: no clips")
        for name, frames in clips:
            if not frames:
                raise ValueError(f"StudyServer: clip {name!r} has no frames")
        self.study = study
        self.clips = [(str(name), list(frames)) for name, frames in clips]
        self.clip_fps = float(clip_fps)
        self.fixation = [float(fixation[0]), float(fixation[1])]
        self.host, self.port = host, port
        self.token = None if is_loopback(host) else secrets.token_urlsafe(16)
        self.done = asyncio.Event()
        self._runner = None

    # ---- requests ------------------------------------------------------------------------------

    def _authorised(self, request) -> bool:
        if self.token is None:
            return True
        return hmac.compare_digest(request.query.get("token", "").encode(), self.token.encode())

    def _same_origin(self, request) -> bool:
        origin = request.headers.get("Origin")
        return origin is None or origin in (f"http://{request.host}", f"https://{request.host}")

    @staticmethod
    def _json(payload, status=200):
        from aiohttp import web

        return web.Response(
            text=json.dumps(payload, allow_nan=False),
            status=status,
            content_type="application/json",
            headers={"Cache-Control": "no-store"},
        )

    def _refused(self, request):
        from aiohttp import web

        if not self._authorised(request):
            return web.Response(status=403, text="fovjax view: a valid ?token= is required\n")
        if request.method == "POST" and not self._same_origin(request):
            log.warning("refused a POST from origin %s", request.headers.get("Origin"))
            return web.Response(status=403, text="fovjax view: cross-origin request refused\n")
        return None

    async def _index(self, request):
        from aiohttp import web

        refused = self._refused(request)
        if refused is not None:
            return refused
        html = _static("study.html").decode()
        return web.Response(text=html, content_type="text/html", headers={"Cache-Control": "no-store"})

    async def _static_file(self, request):
        from aiohttp import web

        name = request.match_info["name"]
        if name not in STUDY_STATIC_FILES:
            raise web.HTTPNotFound()
        return web.Response(body=_static(name), content_type=STUDY_STATIC_FILES[name])

    async def _state(self, request):
        refused = self._refused(request)
        if refused is not None:
            return refused
        state = self.study.state()
        state.update(
            clips=[{"name": name, "frames": len(frames)} for name, frames in self.clips],
            clip_fps=self.clip_fps,
            fixation=self.fixation,
        )
        return self._json(state)

    async def _trial(self, request):
        refused = self._refused(request)
        if refused is not None:
            return refused
        try:
            index = int(request.match_info["index"])
            return self._json(self.study.trial(index))
        except (ValueError, IndexError) as err:
            return self._json({"error": str(err)}, status=400)

    async def _read_json(self, request):
        body = await request.read()
        if len(body) > MAX_ANSWER_BYTES:
            raise ValueError(f"request of {len(body)} bytes exceeds {MAX_ANSWER_BYTES}")
        try:
            payload = json.loads(body)
        except (ValueError, UnicodeDecodeError) as err:
            raise ValueError(f"malformed JSON: {err}") from None
        if not isinstance(payload, dict):
            raise ValueError(f"expected a JSON object, got {type(payload).__name__}")
        return payload

    async def _form(self, request):
        refused = self._refused(request)
        if refused is not None:
            return refused
        try:
            stored = self.study.save_form(await self._read_json(request))
        except ValueError as err:
            log.warning("participant form refused: %s", err)
            return self._json({"error": str(err)}, status=400)
        return self._json({"stored": stored})

    async def _answer(self, request):
        refused = self._refused(request)
        if refused is not None:
            return refused
        try:
            row = self.study.record(await self._read_json(request))
        except ValueError as err:
            log.warning("answer refused: %s", err)
            return self._json({"error": str(err)}, status=400)
        state = self.study.state()
        if state["next"] is None:
            # The response goes out first; whoever awaits `done` stops the server after it.
            asyncio.get_running_loop().call_later(0.2, self.done.set)
        return self._json({"recorded": row, "state": state})

    async def _clip(self, request):
        from aiohttp import web

        refused = self._refused(request)
        if refused is not None:
            return refused
        try:
            name, frames = self.clips[int(request.match_info["clip"])]
            jpeg = frames[int(request.match_info["frame"])]
        except (ValueError, IndexError):
            raise web.HTTPNotFound() from None
        return web.Response(body=jpeg, content_type="image/jpeg", headers={"Cache-Control": "no-store"})

    # ---- life cycle ----------------------------------------------------------------------------

    def app(self):
        from aiohttp import web

        app = web.Application(client_max_size=MAX_ANSWER_BYTES)
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static_file)
        app.router.add_get("/api/state", self._state)
        app.router.add_get("/api/trial/{index}", self._trial)
        app.router.add_post("/api/form", self._form)
        app.router.add_post("/api/answer", self._answer)
        app.router.add_get("/clip/{clip}/{frame}.jpg", self._clip)
        return app

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        query = f"?token={self.token}" if self.token else ""
        return f"http://{host}:{self.port}/{query}"

    async def start(self) -> str:
        from aiohttp import web

        self._runner = web.AppRunner(self.app(), handle_signals=False, access_log=None)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        await site.start()
        if self.port == 0:
            self.port = self._runner.addresses[0][1]
        return self.url

    async def stop(self) -> None:
        if self._runner is not None:
            with contextlib.suppress(Exception):
                await self._runner.cleanup()
