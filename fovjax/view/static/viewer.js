// fovjax view: shows the frames the server streams, sends the mouse gaze and the keys, and
// acknowledges each frame once it is on screen (with the gaze-to-display latency it measured).
"use strict";

const KEYS = {
  ArrowLeft: "head_left", ArrowRight: "head_right", ArrowUp: "head_up", ArrowDown: "head_down",
  "0": "head_reset", q: "fovea_up", a: "fovea_down", w: "periphery_up", s: "periphery_down",
  "1": "preset_1", "2": "preset_2", "3": "preset_3", "4": "preset_4", "5": "preset_5",
  m: "toggle_full", v: "toggle_debug", p: "save",
};

const frameCanvas = document.getElementById("frame");
const marksCanvas = document.getElementById("marks");
const ctx = frameCanvas.getContext("2d");
const marks = marksCanvas.getContext("2d");
const overlay = document.getElementById("overlay");
const statusLine = document.getElementById("status");

// For tests and the curious: the newest frame's statistics and counters.
const view = { stats: null, displayed: 0, latencyMs: null, status: null, saved: null,
  latencies: [], shownAt: [], serverMs: [] };
window.fovjaxView = view;

const token = new URLSearchParams(location.search).get("token");
const wsUrl = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws" +
  (token ? "?token=" + encodeURIComponent(token) : "");
let ws = null;
let pending = null;            // statistics of the frame whose image comes next
const sentGazeTimes = new Set(); // our own mouse events' times (ms), to measure latency
const shownTimes = [];

function send(msg) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg));
}

function fmt(x, digits = 1) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }
function count(x) { return x === null || x === undefined ? "–" : Number(x).toLocaleString("en"); }

function pageFps() {
  if (shownTimes.length < 2) return null;
  return (shownTimes.length - 1) * 1000 / (shownTimes[shownTimes.length - 1] - shownTimes[0]);
}

function drawMarks(s) {
  const w = marksCanvas.width, h = marksCanvas.height;
  marks.clearRect(0, 0, w, h);
  [[s.gaze_left, 0], [s.gaze_right, w / 2]].forEach(([g, x0]) => {
    const x = x0 + g[0] * w / 2, y = g[1] * h;
    marks.strokeStyle = "rgba(0, 255, 255, 0.9)";
    marks.lineWidth = 1;
    marks.beginPath();
    marks.moveTo(x - 8, y); marks.lineTo(x + 8, y); marks.moveTo(x, y - 8); marks.lineTo(x, y + 8);
    marks.stroke();
  });
}

function showOverlay(s, clientMs) {
  const ms = s.ms;
  const lat = s.latency;
  const regions = s.rays_by_region
    ? `fovea ${count(s.rays_by_region.fovea)}  periphery ${count(s.rays_by_region.periphery)}  ` +
      `outside ${count(s.rays_by_region.outside)}  (primary rays; budget ${count(s.budget)})`
    : "– (full quality)";
  const thresholds = s.mode === "full" ? "full quality" :
    `fovea ${fmt(s.fovea_deg)}°  periphery ${fmt(s.periphery_deg)}°`;
  overlay.textContent = [
    `frame ${s.frame}  ${s.mode}  ${s.view} view  2×${s.size[0]}×${s.size[1]}  spp ${s.spp}`,
    `fps ${fmt(pageFps())} (page)  ${fmt(s.fps)} (server)   dropped frames ${s.dropped_frames}` +
      `   ignored messages ${s.ignored_messages}`,
    `gaze→display latency: this frame ${fmt(view.latencyMs)} ms  last ${fmt(lat.last_ms)} ms  ` +
      `median ${fmt(lat.median_ms)} ms  (n=${lat.count})`,
    `ms: gaze ${fmt(ms.gaze)}  render ${fmt(ms.render)}  host ${fmt(ms.host)}  compile ${fmt(ms.compile)}  ` +
      `debug ${fmt(ms.debug)}  encode ${fmt(ms.encode)}  server total ${fmt(ms.frame)}  ` +
      `network+decode ${fmt(clientMs)}`,
    `rays ${count(s.rays)}  (primary ${count(s.primary_rays)}  shadow ${count(s.shadow_rays)}  ` +
      `reflection ${count(s.reflection_rays)}; ${count(s.pixels)} pixels)`,
    `rays per region: ${regions}`,
    `thresholds: ${thresholds}`,
    `tracking: ${s.tracking_state}  gaze ${s.gaze_source}: L (${fmt(s.gaze_left[0], 3)}, ` +
      `${fmt(s.gaze_left[1], 3)})  R (${fmt(s.gaze_right[0], 3)}, ${fmt(s.gaze_right[1], 3)})`,
    ...(s.source_status ? [`gaze source: ${s.source_status}`] : []),
    `head ${s.head_source} (${s.head_state}): yaw ${fmt(s.head_pose[0])}°  pitch ${fmt(s.head_pose[1])}°  ` +
      `roll ${fmt(s.head_pose[2])}°`,
  ].join("\n");
}

async function showFrame(s, blob) {
  const received = performance.now();
  const bitmap = await createImageBitmap(blob);
  if (frameCanvas.width !== bitmap.width || frameCanvas.height !== bitmap.height) {
    frameCanvas.width = marksCanvas.width = bitmap.width;
    frameCanvas.height = marksCanvas.height = bitmap.height;
    // Small frames are shown enlarged (pixelated) so the regions stay visible.
    const scale = Math.max(1, Math.floor(Math.min(1280, window.innerWidth - 24) / bitmap.width));
    for (const c of [frameCanvas, marksCanvas]) {
      c.style.width = bitmap.width * scale + "px";
      c.style.height = bitmap.height * scale + "px";
    }
  }
  ctx.drawImage(bitmap, 0, 0);
  bitmap.close();
  drawMarks(s);
  // The frame is on screen from the next paint: acknowledge it from the animation frame.
  requestAnimationFrame(() => {
    const now = performance.now();
    let latency = null;
    if (s.gaze_new && s.gaze_t !== null && sentGazeTimes.has(s.gaze_t) && now >= s.gaze_t) {
      latency = now - s.gaze_t;
    }
    view.latencyMs = latency;
    if (latency !== null && view.latencies.length < 100000) view.latencies.push(latency);
    if (view.shownAt.length < 100000) { view.shownAt.push(now); view.serverMs.push(s.ms.frame); }
    send({ type: "shown", frame: s.frame, latency_ms: latency });
    shownTimes.push(now);
    if (shownTimes.length > 30) shownTimes.shift();
    view.stats = s;
    view.displayed += 1;
    showOverlay(s, now - received);
  });
}

function connect() {
  ws = new WebSocket(wsUrl);
  ws.binaryType = "blob";
  ws.onopen = () => { statusLine.textContent = "connected"; };
  ws.onclose = (ev) => {
    statusLine.textContent = `disconnected (${ev.code}); reconnecting…`;
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data !== "string") {
      if (pending) { const s = pending; pending = null; showFrame(s, ev.data); }
      return;
    }
    const msg = JSON.parse(ev.data);
    if (msg.type === "frame") {
      pending = msg;
    } else if (msg.type === "status") {
      view.status = msg;
      statusLine.textContent = msg.state + (msg.message ? ": " + msg.message : "");
    } else if (msg.type === "saved") {
      view.saved = msg.paths;
      statusLine.textContent = "saved " + msg.paths.join(", ");
    }
  };
}

frameCanvas.addEventListener("mousemove", (ev) => {
  const r = frameCanvas.getBoundingClientRect();
  const u = (ev.clientX - r.left) / r.width, v = (ev.clientY - r.top) / r.height;
  if (u < 0 || u > 1 || v < 0 || v > 1) return;
  const left = u < 0.5;
  const x = Math.min(1, Math.max(0, left ? 2 * u : 2 * u - 1));
  const y = Math.min(1, Math.max(0, v));
  const t = ev.timeStamp;
  sentGazeTimes.add(t);
  if (sentGazeTimes.size > 500) sentGazeTimes.delete(sentGazeTimes.values().next().value);
  send({ type: "gaze", eye: left ? "left" : "right", x: x, y: y, t: t });
});
frameCanvas.addEventListener("mouseleave", () => send({ type: "leave" }));
window.addEventListener("keydown", (ev) => {
  if (ev.ctrlKey || ev.metaKey || ev.altKey) return;
  const action = KEYS[ev.key];
  if (!action) return;
  ev.preventDefault();
  send({ type: "key", action: action });
});

connect();
