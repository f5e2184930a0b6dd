// fovjax view --xr: the headset page. In an immersive-vr session it sends the head pose and both
// eyes' views every display frame, and draws the newest frame the server rendered into every
// display frame, reprojected (rotation) from the eye cameras it was rendered with to the views
// of that display frame: the frame lies on a sphere at infinity around the eye, so a frame that
// comes late is shown where it belongs, never at a stale orientation. It acknowledges each new
// frame with what it measured: display rate, render rate (new frames reaching the display), the
// rendered head pose's age at display and the reprojection angle.
"use strict";

const XM = window.fovjaxXRMath;
const KEYS = {
  q: "fovea_up", a: "fovea_down", w: "periphery_up", s: "periphery_down",
  "1": "preset_1", "2": "preset_2", "3": "preset_3", "4": "preset_4", "5": "preset_5",
  m: "toggle_full", v: "toggle_debug", p: "save",
};
const RATE_WINDOW = 60;
const HUD_TANGENTS = [-0.45, 0.45, -0.62, -0.42]; // the text panel, head-locked below the centre

const enterButton = document.getElementById("enter");
const statusLine = document.getElementById("status");
const gazeLine = document.getElementById("gaze");
const supportLine = document.getElementById("support");
const preview = document.getElementById("preview");
const previewCtx = preview.getContext("2d");
const overlay = document.getElementById("overlay");

// For tests and the curious: the page's state and measurements.
const xr = {
  mode: "2d",            // "2d" or "vr"
  supported: null,       // immersive-vr available (null: not checked yet)
  reason: null,          // why not, when not
  info: null,            // the server's xr_info (gaze, scale)
  status: null,          // the server's newest status
  stats: null,           // the newest frame's statistics
  shownStats: null,      // the statistics of the frame in the headset now
  sessions: 0,
  ended: 0,
  displayFrames: 0,      // display frames drawn since Enter VR
  framesShown: 0,        // new frames drawn into the headset, all sessions
  posesSent: 0,
  lastPose: null,        // the newest pose message sent
  displayHz: null,
  renderHz: null,
  poseAgeMs: null,
  reprojectionDeg: null,
  hold: false,
  hud: true,
  error: null,
  setHold,
};
window.fovjaxXR = xr;

const token = new URLSearchParams(location.search).get("token");
const wsUrl = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws" +
  (token ? "?token=" + encodeURIComponent(token) : "");
let ws = null;
let pendingStats = null;   // statistics of the frame whose image comes next
let unsupportedSent = false;

let gl = null, program = null, uniforms = null, frameTexture = null, panelTexture = null, hudTexture = null;
let frameTextureWidth = 1;
let session = null, refSpace = null;
let current = null;        // the frame in the headset: {stats, shown}
let heldBack = null;       // the newest frame received while holding: {stats, bitmap}
const displayTimes = [];
const shownTimes = [];
let lastTextUpdate = 0;

function send(msg) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg));
}

function sendState(state, reason) { send({ type: "xr_state", state: state, reason: reason.slice(0, 300) }); }

function fmt(x, digits = 1) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }
function count(x) { return x === null || x === undefined ? "–" : Number(x).toLocaleString("en"); }

function rate(times) {
  if (times.length < 2 || times[times.length - 1] === times[0]) return null;
  return (times.length - 1) * 1000 / (times[times.length - 1] - times[0]);
}

function push(times, t) {
  times.push(t);
  if (times.length > RATE_WINDOW) times.shift();
}

// ---- the 2D page ---------------------------------------------------------------------------------

function setStatus(text) { statusLine.textContent = text; drawPanelText(); }

function unsupported(reason) {
  xr.supported = false;
  xr.reason = reason;
  enterButton.disabled = true;
  supportLine.textContent = reason;
  supportLine.className = "unsupported";
  if (!unsupportedSent && ws && ws.readyState === WebSocket.OPEN) {
    unsupportedSent = true;
    sendState("unsupported", reason);
  }
}

async function checkSupport() {
  if (!window.isSecureContext) {
    unsupported(`no WebXR: ${location.origin} is not a secure origin; open the page as http://localhost:PORT ` +
      "(forward the port: adb reverse, ssh -L) or over https, or allow this origin in " +
      "chrome://flags/#unsafely-treat-insecure-origin-as-secure");
    return;
  }
  if (!navigator.xr) {
    unsupported("no WebXR in this browser (navigator.xr is missing): use the headset's browser, or Chrome/Edge " +
      "with an OpenXR runtime");
    return;
  }
  let ok = false;
  try {
    ok = await navigator.xr.isSessionSupported("immersive-vr");
  } catch (err) {
    unsupported(`WebXR refused the check for immersive-vr: ${err.name}: ${err.message}`);
    return;
  }
  if (!ok) {
    unsupported("WebXR is here but no immersive-vr device: connect a headset (its OpenXR runtime running) " +
      "or open this page in the headset's browser");
    return;
  }
  xr.supported = true;
  supportLine.textContent = "WebXR immersive-vr available";
  supportLine.className = "";
  enterButton.disabled = session !== null;
}

function drawPreview(bitmap) {
  if (preview.width !== bitmap.width || preview.height !== bitmap.height) {
    preview.width = bitmap.width;
    preview.height = bitmap.height;
    const scale = Math.max(1, Math.floor(Math.min(1280, window.innerWidth - 24) / bitmap.width));
    preview.style.width = bitmap.width * scale + "px";
    preview.style.height = bitmap.height * scale + "px";
  }
  previewCtx.drawImage(bitmap, 0, 0);
}

function showOverlay() {
  const s = xr.shownStats || xr.stats;
  if (!s) return;
  const ms = s.ms;
  const regions = s.rays_by_region
    ? `fovea ${count(s.rays_by_region.fovea)}  periphery ${count(s.rays_by_region.periphery)}  ` +
      `outside ${count(s.rays_by_region.outside)}  (primary rays; budget ${count(s.budget)})`
    : "– (full quality)";
  const thresholds = s.mode === "full" ? "full quality" :
    `fovea ${fmt(s.fovea_deg)}°  periphery ${fmt(s.periphery_deg)}°`;
  overlay.textContent = [
    `${xr.mode === "vr" ? "in VR" : "2D page"}  frame ${s.frame}  ${s.mode}  ${s.view} view  ` +
      `2×${s.size[0]}×${s.size[1]}  spp ${s.spp}${xr.hold ? "  HOLD" : ""}`,
    `display ${fmt(xr.displayHz)} Hz   render ${fmt(xr.renderHz)} Hz (page)  ${fmt(s.fps)} Hz (server)` +
      `   dropped frames ${s.dropped_frames}`,
    `head pose age at display ${fmt(xr.poseAgeMs)} ms   reprojection ${fmt(xr.reprojectionDeg, 2)}°`,
    `ms: rig ${fmt(ms.rig)}  gaze ${fmt(ms.gaze)}  render ${fmt(ms.render)}  host ${fmt(ms.host)}  ` +
      `compile ${fmt(ms.compile)}  encode ${fmt(ms.encode)}  server total ${fmt(ms.frame)}`,
    `rays ${count(s.rays)}  (primary ${count(s.primary_rays)}  shadow ${count(s.shadow_rays)}  ` +
      `reflection ${count(s.reflection_rays)}; ${count(s.pixels)} pixels)`,
    `rays per region: ${regions}`,
    `thresholds: ${thresholds}`,
    `gaze: ${s.gaze_source} (${s.tracking_state})  L (${fmt(s.gaze_left[0], 3)}, ${fmt(s.gaze_left[1], 3)})  ` +
      `R (${fmt(s.gaze_right[0], 3)}, ${fmt(s.gaze_right[1], 3)})`,
    ...(s.source_status ? [`gaze source: ${s.source_status}`] : []),
    `head (headset): yaw ${fmt(s.head_pose[0])}°  pitch ${fmt(s.head_pose[1])}°  roll ${fmt(s.head_pose[2])}°  ` +
      `position (${s.head_position.map((v) => fmt(v, 3)).join(", ")}) m`,
    `eyes: IPD ${fmt(1000 * s.xr.ipd_m)} mm  toe-out ${fmt(s.xr.toe_out_deg, 2)}°  rig fit: eye position ` +
      `${fmt(1000 * s.xr.position_error_m, 2)} mm, rotation ${fmt(s.xr.rotation_error_deg, 2)}°`,
  ].join("\n");
}

// ---- frames from the server ------------------------------------------------------------------------

function acknowledge(s, measured) {
  send({
    type: "shown", frame: s.frame,
    display_hz: measured ? xr.displayHz : null,
    render_hz: measured ? xr.renderHz : null,
    pose_age_ms: measured ? xr.poseAgeMs : null,
    reprojection_deg: measured ? xr.reprojectionDeg : null,
  });
}

async function receive(s, blob) {
  const bitmap = await createImageBitmap(blob);
  xr.stats = s;
  drawPreview(bitmap);
  if (xr.mode === "vr" && gl) {
    if (xr.hold) {
      // Not acknowledged: the server renders no more than one frame a second meanwhile.
      if (heldBack) heldBack.bitmap.close();
      heldBack = { stats: s, bitmap: bitmap };
      return;
    }
    upload(s, bitmap);
    return;
  }
  // Outside a session (a frame in flight when it ended): it is on the 2D page.
  bitmap.close();
  requestAnimationFrame(() => { acknowledge(s, false); showOverlay(); });
}

function upload(s, bitmap) {
  gl.bindTexture(gl.TEXTURE_2D, frameTexture);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, bitmap);
  frameTextureWidth = bitmap.width;
  bitmap.close();
  current = { stats: s, shown: false };
}

function setHold(on) {
  xr.hold = Boolean(on);
  if (!xr.hold && heldBack) {
    const { stats, bitmap } = heldBack;
    heldBack = null;
    if (xr.mode === "vr" && gl) upload(stats, bitmap);
    else { bitmap.close(); acknowledge(stats, false); }
  }
  showOverlay();
}

function connect() {
  ws = new WebSocket(wsUrl);
  ws.binaryType = "blob";
  ws.onopen = () => {
    setStatus("connected");
    unsupportedSent = false;
    if (xr.supported === false) unsupported(xr.reason);
  };
  ws.onclose = (ev) => {
    setStatus(`disconnected (${ev.code}); reconnecting…`);
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data !== "string") {
      if (pendingStats) { const s = pendingStats; pendingStats = null; receive(s, ev.data); }
      return;
    }
    const msg = JSON.parse(ev.data);
    if (msg.type === "frame") {
      pendingStats = msg;
    } else if (msg.type === "status") {
      xr.status = msg;
      setStatus(msg.state + (msg.message ? ": " + msg.message : ""));
    } else if (msg.type === "xr_info") {
      xr.info = msg;
      gazeLine.textContent = `gaze: ${msg.gaze}   resolution: ${msg.scale}× the headset's`;
    } else if (msg.type === "saved") {
      setStatus("saved " + msg.paths.join(", "));
    }
  };
}

// ---- WebGL: the reprojection --------------------------------------------------------------------

const VERTEX = `#version 300 es
const vec2 corners[3] = vec2[3](vec2(-1.0, -1.0), vec2(3.0, -1.0), vec2(-1.0, 3.0));
out vec2 ndc;
void main() { ndc = corners[gl_VertexID]; gl_Position = vec4(ndc, 0.0, 1.0); }`;

// Per display pixel (xr_math.js's frameUV): its ray in the displayed view, turned into the
// rendered eye's frame, looked up in that eye's half of the frame.
const FRAGMENT = `#version 300 es
precision highp float;
in vec2 ndc;
uniform mat4 invProj;
uniform mat3 renderFromView;
uniform vec4 tangents;
uniform vec3 uRange;
uniform bool discardOutside;
uniform sampler2D image;
out vec4 colour;
void main() {
  vec4 p = invProj * vec4(ndc, -1.0, 1.0);
  vec3 d = renderFromView * (p.xyz / p.w);
  vec2 uv = vec2(-1.0);
  if (d.z < 0.0) {
    vec2 t = d.xy / -d.z;
    uv = vec2((t.x - tangents.x) / (tangents.y - tangents.x), (tangents.w - t.y) / (tangents.w - tangents.z));
  }
  if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) {
    if (discardOutside) discard;
    colour = vec4(0.02, 0.02, 0.03, 1.0);
    return;
  }
  float u = clamp(mix(uRange.x, uRange.y, uv.x), uRange.x + uRange.z, uRange.y - uRange.z);
  colour = texture(image, vec2(u, uv.y));
}`;

function compile(type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
  return shader;
}

function makeTexture() {
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  return texture;
}

function initGL() {
  const canvas = document.createElement("canvas");
  gl = canvas.getContext("webgl2", { xrCompatible: true, antialias: false, alpha: false, depth: false });
  if (!gl) throw new Error("this browser has no WebGL2");
  program = gl.createProgram();
  gl.attachShader(program, compile(gl.VERTEX_SHADER, VERTEX));
  gl.attachShader(program, compile(gl.FRAGMENT_SHADER, FRAGMENT));
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  uniforms = {};
  for (const name of ["invProj", "renderFromView", "tangents", "uRange", "discardOutside", "image"]) {
    uniforms[name] = gl.getUniformLocation(program, name);
  }
  gl.bindVertexArray(gl.createVertexArray());
  frameTexture = makeTexture();
  panelTexture = makeTexture();
  hudTexture = makeTexture();
  drawPanelText();
}

// Text panels as textures: the placeholder before the first frame, and the headset's stats.
const panelCanvas = document.createElement("canvas");
panelCanvas.width = 512; panelCanvas.height = 256;
const hudCanvas = document.createElement("canvas");
hudCanvas.width = 512; hudCanvas.height = 118;

function drawText(canvas, lines, size) {
  const ctx = canvas.getContext("2d");
  ctx.fillStyle = "rgba(10, 10, 14, 1)";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#e8e8e8";
  ctx.font = `${size}px monospace`;
  lines.forEach((line, i) => ctx.fillText(line, 12, 12 + (i + 1) * size * 1.25));
}

function drawPanelText() {
  if (!gl) return;
  const status = xr.status ? xr.status.state + (xr.status.message ? ": " + xr.status.message : "") : "connecting";
  const words = ("fovjax view: " + status).split(" ");
  const lines = [];
  for (const word of words) {
    if (lines.length && (lines[lines.length - 1] + " " + word).length <= 34) lines[lines.length - 1] += " " + word;
    else lines.push(word);
  }
  drawText(panelCanvas, lines.slice(0, 8), 24);
  gl.bindTexture(gl.TEXTURE_2D, panelTexture);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, panelCanvas);
}

function drawHudText() {
  const gaze = xr.info ? xr.info.gaze : "–";
  drawText(hudCanvas, [
    `display ${fmt(xr.displayHz)} Hz  render ${fmt(xr.renderHz)} Hz${xr.hold ? "  HOLD" : ""}`,
    `pose age ${fmt(xr.poseAgeMs, 0)} ms  reprojection ${fmt(xr.reprojectionDeg, 1)}°`,
    `gaze: ${gaze}`.slice(0, 40),
  ], 22);
  gl.bindTexture(gl.TEXTURE_2D, hudTexture);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, hudCanvas);
}

const IDENTITY3 = [1, 0, 0, 0, 1, 0, 0, 0, 1];

function projectionTangents(p) {
  return [(p[8] - 1) / p[0], (p[8] + 1) / p[0], (p[9] - 1) / p[5], (p[9] + 1) / p[5]];
}

function draw(texture, invProj, renderFromView, tangents, uRange, discardOutside) {
  gl.useProgram(program);
  gl.activeTexture(gl.TEXTURE0);
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.uniform1i(uniforms.image, 0);
  gl.uniformMatrix4fv(uniforms.invProj, false, invProj);
  gl.uniformMatrix3fv(uniforms.renderFromView, false, XM.mat3Transpose(renderFromView)); // column-major
  gl.uniform4fv(uniforms.tangents, tangents);
  gl.uniform3fv(uniforms.uRange, uRange);
  gl.uniform1i(uniforms.discardOutside, discardOutside ? 1 : 0);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
}

// ---- the immersive session -------------------------------------------------------------------------

function r(x, scale) { return Math.round(x * scale) / scale; }
function vec3(p) { return [r(p.x, 1e6), r(p.y, 1e6), r(p.z, 1e6)]; }
function quat(o) { return [r(o.x, 1e6), r(o.y, 1e6), r(o.z, 1e6), r(o.w, 1e6)]; }

function poseMessage(t, pose, layer) {
  const views = [];
  for (const view of pose.views) {
    const vp = layer.getViewport(view);
    if ((view.eye !== "left" && view.eye !== "right") || !vp || vp.width < 1 || vp.height < 1) return null;
    views.push({
      eye: view.eye,
      position: vec3(view.transform.position),
      orientation: quat(view.transform.orientation),
      projection: Array.from(view.projectionMatrix, (v) => r(v, 1e7)),
      viewport: [vp.width, vp.height],
    });
  }
  if (views.length !== 2 || views[0].eye === views[1].eye) return null;
  return {
    type: "xr_pose", t: r(t, 1e3),
    head: { position: vec3(pose.transform.position), orientation: quat(pose.transform.orientation) },
    views: views,
  };
}

function onXRFrame(time, frame) {
  const s = frame.session;
  s.requestAnimationFrame(onXRFrame);
  // The time this display frame is shown at (the page's clock), where the browser says it.
  const now = frame.predictedDisplayTime || time;
  const pose = frame.getViewerPose(refSpace);
  if (!pose) return; // tracking lost: nothing new to draw
  const layer = s.renderState.baseLayer;
  const message = poseMessage(now, pose, layer);
  if (message === null) {
    xr.error = "this device gives no left and right views: a headset is needed";
    sendState("failed", xr.error);
    s.end();
    return;
  }
  send(message);
  xr.posesSent += 1;
  xr.lastPose = message;
  push(displayTimes, now);
  xr.displayHz = rate(displayTimes);
  const headQ = message.head.orientation;
  if (current) {
    xr.poseAgeMs = now - current.stats.xr.pose_t;
    xr.reprojectionDeg = XM.angleDeg(current.stats.xr.head_orientation, headQ);
  }
  gl.bindFramebuffer(gl.FRAMEBUFFER, layer.framebuffer);
  gl.clearColor(0, 0, 0, 1);
  gl.clear(gl.COLOR_BUFFER_BIT);
  if (now - lastTextUpdate > 250) {
    lastTextUpdate = now;
    if (xr.hud) drawHudText();
    showOverlay();
  }
  for (const view of pose.views) {
    const vp = layer.getViewport(view);
    gl.viewport(vp.x, vp.y, vp.width, vp.height);
    const projection = Array.from(view.projectionMatrix);
    const invProj = XM.mat4Invert(projection);
    if (!invProj) continue;
    const viewQ = quat(view.transform.orientation);
    if (current) {
      const eye = view.eye === "right" ? 1 : 0;
      const rendered = current.stats.xr.eyes[eye];
      const half = 0.5 / frameTextureWidth;
      draw(frameTexture, invProj, XM.renderFromView(rendered.rotation, viewQ), rendered.tangents,
        [0.5 * eye, 0.5 * eye + 0.5, half], false);
    } else {
      draw(panelTexture, invProj, IDENTITY3, projectionTangents(projection), [0, 1, 0], false);
    }
    if (xr.hud) draw(hudTexture, invProj, IDENTITY3, HUD_TANGENTS, [0, 1, 0], true);
  }
  xr.displayFrames += 1;
  if (current && !current.shown) {
    current.shown = true;
    xr.framesShown += 1;
    xr.shownStats = current.stats;
    push(shownTimes, now);
    xr.renderHz = rate(shownTimes);
    acknowledge(current.stats, true);
  }
}

function failed(reason) {
  xr.error = reason;
  setStatus(reason);
  sendState("failed", reason);
  enterButton.disabled = !xr.supported;
}

async function enterVR() {
  enterButton.disabled = true;
  let started;
  try {
    started = await navigator.xr.requestSession("immersive-vr");
  } catch (err) {
    failed(`could not start a VR session: ${err.name}: ${err.message}`);
    return;
  }
  try {
    if (!gl) initGL();
    await gl.makeXRCompatible();
    const layer = new XRWebGLLayer(started, gl);
    started.updateRenderState({ baseLayer: layer, depthNear: 0.1, depthFar: 1000 });
    refSpace = await started.requestReferenceSpace("local");
    session = started;
    session.addEventListener("end", onSessionEnd);
    xr.mode = "vr";
    xr.sessions += 1;
    xr.displayFrames = 0;
    xr.error = null;
    displayTimes.length = 0;
    shownTimes.length = 0;
    current = null;
    document.body.classList.add("in-vr");
    enterButton.textContent = "in VR";
    setStatus("in VR: waiting for the first frame");
    sendState("entered", `immersive-vr, framebuffer ${layer.framebufferWidth}x${layer.framebufferHeight}`);
    session.requestAnimationFrame(onXRFrame);
  } catch (err) {
    started.end().catch(() => {});
    failed(`could not set up the VR session: ${err.name}: ${err.message}`);
  }
}

function onSessionEnd() {
  session = null;
  xr.mode = "2d";
  xr.ended += 1;
  // A frame received and not yet in the headset is on the 2D page: acknowledged as shown there.
  if (current && !current.shown) acknowledge(current.stats, false);
  current = null;
  if (heldBack) { heldBack.bitmap.close(); acknowledge(heldBack.stats, false); heldBack = null; }
  sendState("ended", "");
  document.body.classList.remove("in-vr");
  enterButton.textContent = "Enter VR";
  enterButton.disabled = !xr.supported;
  setStatus("left VR: back to the 2D page");
  showOverlay();
}

enterButton.addEventListener("click", enterVR);
window.addEventListener("keydown", (ev) => {
  if (ev.ctrlKey || ev.metaKey || ev.altKey) return;
  if (ev.key === "f") { ev.preventDefault(); setHold(!xr.hold); return; }
  if (ev.key === "h") { ev.preventDefault(); xr.hud = !xr.hud; return; }
  const action = KEYS[ev.key];
  if (!action) return;
  ev.preventDefault();
  send({ type: "key", action: action });
});

connect();
checkSupport();
