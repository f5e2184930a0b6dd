"""The headset page's server (`fovjax view --xr`): the 2D viewer's server (`Viewer`: one frame in
flight, the newest input at each frame's start, the same safety) serving static/xr.html, whose
immersive-vr session sends the headset pose every display frame.

Frames are rendered only while the active page is in a session (`XRRenderer.in_session`), each
for the newest pose. The page draws the newest frame into every display frame, reprojected to
that frame's head pose, and acknowledges each new frame with its measurements (display rate,
the rate new frames reach the display, the rendered pose's age at display, the reprojection
angle), which the server logs, one line per frame, on the ``fovjax.view.xr`` logger.
"""

from __future__ import annotations

import collections
import logging

from ._protocol import MessageError
from ._server import ACK_TIMEOUT_S, STATIC_FILES, Viewer
from ._xr_protocol import parse_xr_message

log = logging.getLogger("fovjax.view.xr")

XR_STATIC_FILES = {
    **STATIC_FILES,
    "xr.js": "application/javascript",
    "xr_math.js": "application/javascript",
    "xr.css": "text/css",
}
DISPLAY_WINDOW = 600  # the frames whose display measurements are kept (`display_log`)


class XRViewer(Viewer):
    """The server around an `XRRenderer` (see the module docstring); arguments as `Viewer`'s.
    `display_log`: the newest frames' page measurements (dicts: frame, display_hz, render_hz,
    pose_age_ms, reprojection_deg, render_ms)."""

    PAGE = "xr.html"
    STATIC_FILES = XR_STATIC_FILES

    def __init__(self, renderer, **kwargs):
        super().__init__(renderer, **kwargs)
        self.display_log: collections.deque = collections.deque(maxlen=DISPLAY_WINDOW)
        self._pose_client = None
        self._refused_poses: set[str] = set()

    def _has_work(self) -> bool:
        return self.renderer.in_session and self._pose_client is self.clients[0]

    def _ack_grace(self, frame) -> float:
        # The page shows a frame at its next display frame: a frame done while the previous
        # one waits for that is kept (the reprojection turns it to the newest pose), not dropped
        # and rendered again.
        display_hz = self.display_log[-1]["display_hz"] if self.display_log else None
        interval = 1.5 / display_hz if display_hz else 0.0
        return min(ACK_TIMEOUT_S, max(super()._ack_grace(frame), interval))

    async def _websocket(self, request):
        try:
            return await super()._websocket(request)
        finally:
            if self._pose_client is not None and self._pose_client not in self.clients:
                self._pose_client = None
                self.renderer.end_session()

    async def _announce(self) -> None:
        await super()._announce()
        for client in self.clients:
            await self._send_json(
                client,
                {"type": "xr_info", "gaze": self.renderer.gaze_description, "scale": self.renderer.scale},
            )

    async def _on_message(self, client, data) -> None:
        try:
            msg = parse_xr_message(data)
        except MessageError as err:
            self._ignore(client, str(err))
            return
        kind = msg["type"]
        if kind == "shown":
            self._on_xr_shown(client, msg)
            return
        if kind == "key":
            await super()._on_message(client, data)
            return
        if not self.clients or client is not self.clients[0]:
            self._ignore(client, f"{kind} message from a client waiting its turn")
            return
        if kind == "xr_state":
            await self._on_state(client, msg["state"], msg["reason"])
        else:
            await self._on_pose(client, msg["pose"])

    async def _on_state(self, client, state: str, reason: str) -> None:
        if state == "entered":
            log.info(
                "client %s entered VR (%s); gaze: %s", client.peer, reason, self.renderer.gaze_description
            )
        elif state == "ended":
            log.info("client %s left VR: back to the 2D page", client.peer)
            self._pose_client = None
            self.renderer.end_session()
        else:  # one line, whatever the page's browser lacks
            log.warning("the page at %s cannot enter VR: %s", client.peer, reason)

    async def _on_pose(self, client, pose) -> None:
        try:
            new_shape = self.renderer.set_pose(pose)
        except ValueError as err:
            # The headset's views cannot be rendered (e.g. too many pixels at this scale): the
            # page and the log say why, once per reason.
            if str(err) not in self._refused_poses:
                self._refused_poses.add(str(err))
                log.warning("cannot render the headset's views: %s", err)
                await self._send_json(client, {"type": "status", "state": "error", "message": str(err)})
            return
        if self._pose_client is not client:
            self._pose_client = client
            self._wake.set()
        if new_shape:
            size = self.renderer.scale
            log.info("new headset views (scale %g): the first frame for them compiles", size)
            await self._send_json(
                client,
                {
                    "type": "status",
                    "state": "compiling",
                    "message": "compiling the frame program for the headset's views (once per view size)",
                },
            )

    def _on_xr_shown(self, client, msg) -> None:
        frame = self._sent.get(msg["frame"])
        displayed = self.displayed
        self._on_shown(client, msg)
        if self.displayed == displayed or frame is None or msg["display_hz"] is None:
            return  # ignored (not the frame awaited), or shown on the 2D page after the session
        entry = {
            "frame": msg["frame"],
            "display_hz": msg["display_hz"],
            "render_hz": msg["render_hz"],
            "pose_age_ms": msg["pose_age_ms"],
            "reprojection_deg": msg["reprojection_deg"],
            "render_ms": frame.stats["ms"]["frame"],
        }
        self.display_log.append(entry)
        w, h = frame.stats["size"]

        def number(value, unit, digits=1):
            return "–" if value is None else f"{value:.{digits}f}{unit}"

        log.info(
            "xr frame %d: 2x%dx%d %s, render %s, render rate %s, display %s, head pose age at display %s, "
            "reprojection %s",
            entry["frame"],
            w,
            h,
            frame.stats["mode"],
            number(entry["render_ms"], " ms"),
            number(entry["render_hz"], " Hz"),
            number(entry["display_hz"], " Hz"),
            number(entry["pose_age_ms"], " ms"),
            number(entry["reprojection_deg"], "°", 2),
        )
