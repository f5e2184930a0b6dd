// fovjax study player: runs one test of the thesis's user study (pair, ramp or slider) with a
// participant. The clips are decoded into memory before the test starts; each trial's segments
// (black gaps, reference, foveated levels) are drawn on requestAnimationFrame for their protocol
// durations, rounded to the nearest display frame, and the timestamp of the frame that first drew
// each segment is sent with the answer, so the record holds what was actually shown.
"use strict";

const token = new URLSearchParams(location.search).get("token");
const api = (path) => path + (token ? (path.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(token) : "");
const $ = (id) => document.getElementById(id);
const canvas = $("stimulus"), marksCanvas = $("marks");
const ctx = canvas.getContext("2d"), marks = marksCanvas.getContext("2d");

// For tests and the curious: where the page is and what it measured.
const study = { phase: "loading", state: null, trial: null, recorded: [], error: null, frameMs: null,
  segment: null, sliderLevel: null, sliderOpened: 0 };
window.fovjaxStudy = study;

let clips = [];          // clips[c][f]: ImageBitmap
let clipFps = 30;
let fixation = [0.5, 0.5];

function show(id, visible) { $(id).hidden = !visible; }
function message(text, error = false) {
  $("message").textContent = text;
  $("message").className = error ? "error" : "";
  if (error) study.error = text;
}

async function getJSON(path) {
  const r = await fetch(api(path), { cache: "no-store" });
  const body = await r.json();
  if (!r.ok) throw new Error(body.error || r.statusText);
  return body;
}

async function postJSON(path, payload) {
  const r = await fetch(api(path), { method: "POST", body: JSON.stringify(payload),
    headers: { "Content-Type": "application/json" } });
  const body = await r.json();
  if (!r.ok) throw new Error(body.error || r.statusText);
  return body;
}

function median(xs) {
  const s = [...xs].sort((a, b) => a - b);
  return s.length ? s[Math.floor(s.length / 2)] : null;
}

// The display's frame interval: the median of `n` requestAnimationFrame intervals.
function measureFrames(n) {
  return new Promise((resolve) => {
    const times = [];
    const tick = (now) => {
      times.push(now);
      drawBlack();
      if (times.length > n) resolve(median(times.slice(1).map((t, i) => t - times[i])));
      else requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
  });
}

function drawBlack() {
  ctx.fillStyle = "#000";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
}

function drawClip(c, sinceMs) {
  const frames = clips[c];
  const n = frames.length;
  // Ping-pong: forwards then backwards, so a loop never jumps back to the start.
  const period = Math.max(1, 2 * (n - 1));
  const p = Math.floor(sinceMs * clipFps / 1000) % period;
  const f = n < 2 ? 0 : (p < n ? p : period - p);
  ctx.drawImage(frames[f], 0, 0);
}

function drawFixation() {
  // The thesis's participants fixated a marked point: a cross at the fixation in each eye.
  const w = marksCanvas.width, h = marksCanvas.height;
  marks.clearRect(0, 0, w, h);
  const arm = Math.max(3, Math.round(h / 40));
  marks.strokeStyle = "rgba(255, 40, 40, 0.95)";
  marks.lineWidth = Math.max(1, Math.round(h / 200));
  for (const x0 of [0, w / 2]) {
    const x = x0 + fixation[0] * w / 2, y = fixation[1] * h;
    marks.beginPath();
    marks.moveTo(x - arm, y); marks.lineTo(x + arm, y); marks.moveTo(x, y - arm); marks.lineTo(x, y + arm);
    marks.stroke();
  }
}

async function loadClips(list) {
  let done = 0;
  const total = list.reduce((a, c) => a + c.frames, 0);
  clips = [];
  for (let c = 0; c < list.length; c++) {
    const frames = await Promise.all(Array.from({ length: list[c].frames }, async (_, f) => {
      const r = await fetch(api(`clip/${c}/${f}.jpg`));
      if (!r.ok) throw new Error(`clip ${c} frame ${f}: ${r.status}`);
      const bitmap = await createImageBitmap(await r.blob());
      done += 1;
      message(`loading the sequences… ${done}/${total} frames`);
      return bitmap;
    }));
    clips.push(frames);
  }
  const first = clips[0][0];
  canvas.width = marksCanvas.width = first.width;
  canvas.height = marksCanvas.height = first.height;
  // Small clips are shown enlarged (pixelated), as large as the window allows.
  const scale = Math.max(1, Math.min((window.innerWidth - 24) / first.width, (window.innerHeight * 0.7) / first.height));
  for (const c of [canvas, marksCanvas]) {
    c.style.width = Math.floor(first.width * scale) + "px";
    c.style.height = Math.floor(first.height * scale) + "px";
  }
  drawBlack();
  drawFixation();
}

// ---- the player ------------------------------------------------------------------------------
//
// Plays a queue of segments {kind, seconds, clip}. A segment with seconds ends at its scheduled
// time (the previous one's scheduled end plus its own length, so rounding never accumulates),
// switching at the frame nearest that time; one without (the slider's level) lasts until more
// segments are queued. Every segment's onset is the requestAnimationFrame timestamp of the
// first frame that drew it.
class Player {
  constructor(frameMs) {
    this.frameMs = frameMs;
    this.queue = []; this.onsets = []; this.frames = []; this.deltas = [];
    this.k = -1; this.scheduled = null; this.last = null; this.stopped = false;
    this.onEnd = null; this.onOpen = null; this.endMs = null;
  }
  add(segments) { this.queue.push(...segments); }
  start() { requestAnimationFrame((t) => this.tick(t)); }
  stopAt(ms) { this.stopped = true; this.endMs = ms; }
  tick(now) {
    if (this.last !== null) this.deltas.push(now - this.last);
    this.last = now;
    if (this.stopped) { drawBlack(); return; }
    if (this.k < 0) { this.enter(0, now, now); }
    for (;;) {
      const seg = this.queue[this.k];
      if (seg.seconds === null) {
        if (this.k + 1 < this.queue.length) { this.enter(this.k + 1, now, now); continue; }
        break;
      }
      const end = this.scheduled + seg.seconds * 1000;
      if (now < end - this.frameMs / 2) break;
      if (this.k + 1 >= this.queue.length) {  // the last segment is over
        this.endMs = now; this.stopped = true; drawBlack();
        if (this.onEnd) this.onEnd(now);
        return;
      }
      this.enter(this.k + 1, end, now);
    }
    const seg = this.queue[this.k];
    if (seg.kind === "black") drawBlack(); else drawClip(seg.clip, now - this.onsets[this.k]);
    this.frames[this.k] += 1;
    requestAnimationFrame((t) => this.tick(t));
  }
  enter(k, scheduled, now) {
    this.k = k; this.scheduled = scheduled;
    this.onsets.push(now); this.frames.push(0);
    study.segment = this.queue[k];
    if (this.onOpen) this.onOpen(this.queue[k].seconds === null);
  }
  measured() {
    const late = this.deltas.filter((d) => d > 1.5 * this.frameMs).length;
    return { onsets_ms: this.onsets, stimulus_end_ms: this.endMs, frames: this.frames,
      frame_interval_ms: median(this.deltas) || this.frameMs, frames_drawn: this.deltas.length + 1,
      late_frames: late, time_origin_ms: performance.timeOrigin };
  }
}

function waitClick(buttons) {
  return new Promise((resolve) => {
    const handlers = [];
    const finish = (value, ev) => {
      handlers.forEach(([b, h]) => b.removeEventListener("click", h));
      document.removeEventListener("keydown", onKey);
      resolve([value, ev.timeStamp]);
    };
    const onKey = (ev) => {
      const hit = buttons.find(([, , key]) => key === ev.key);
      if (hit && !hit[0].disabled) { ev.preventDefault(); finish(hit[1], ev); }
    };
    for (const [button, value] of buttons) {
      const h = (ev) => finish(value, ev);
      handlers.push([button, h]);
      button.addEventListener("click", h);
    }
    document.addEventListener("keydown", onKey);
  });
}

async function fixedTrial(trial, frameMs) {
  const player = new Player(frameMs);
  player.add(trial.segments);
  const ended = new Promise((resolve) => { player.onEnd = resolve; });
  study.phase = "playing";
  message("");
  player.start();
  await ended;
  // The answer buttons appear with the black that ends the stimulus.
  const box = $("answers");
  box.textContent = "";
  const buttons = trial.choices.map((c, i) => {
    const b = document.createElement("button");
    b.id = "answer-" + c.value;
    b.textContent = `${i + 1}  ${c.label}`;
    box.appendChild(b);
    return [b, c.value, String(i + 1)];
  });
  $("question").textContent = trial.question;
  show("question-box", true);
  study.phase = "answering";
  const [answer, at] = await waitClick(buttons);
  study.phase = "saving";
  show("question-box", false);
  return { answer, measured: { ...player.measured(), answer_ms: at } };
}

async function sliderTrial(trial, frameMs) {
  const s = trial.slider;
  let level = s.start;
  const actions = [];
  const player = new Player(frameMs);
  player.add(trial.segments);
  const gap = { kind: "black", seconds: s.gap_s, clip: null };
  const levelSegment = () => ({ kind: "foveated", seconds: null, clip: s.clips[level] });
  const lower = $("slider-lower"), higher = $("slider-higher"), ref = $("slider-reference");
  const choose = $("slider-choose");
  const setEnabled = (open) => {
    // Actions only while a level is on screen: each one's segments follow it in the record.
    lower.disabled = !open || level === 0;
    higher.disabled = !open || level === s.levels.length - 1;
    ref.disabled = choose.disabled = !open;
    study.phase = open ? "slider" : "playing";
    if (open) study.sliderOpened += 1;  // for tests: a level is on screen again after an action
    study.sliderLevel = s.levels[level];
    $("slider-level").textContent = open ? `Level ${level + 1} of ${s.levels.length}` : "…";
  };
  player.onOpen = setEnabled;
  setEnabled(false);
  show("slider-box", true);
  message("");
  player.start();
  for (;;) {
    const [action, at] = await waitClick([[lower, "lower", "ArrowDown"], [higher, "higher", "ArrowUp"],
      [ref, "reference", "r"], [choose, "choose", "Enter"]]);
    if (action === "choose") {
      player.stopAt(at);
      break;
    }
    setEnabled(false);
    actions.push({ action, at_ms: at });
    if (action === "reference") {
      player.add([gap, { kind: "reference", seconds: s.reference_s, clip: s.reference_clip }, gap, levelSegment()]);
    } else {
      level += action === "higher" ? 1 : -1;
      player.add([gap, levelSegment()]);
    }
  }
  study.phase = "saving";
  show("slider-box", false);
  const answer = trial.choices[level].value;
  const measured = { ...player.measured(), answer_ms: player.endMs, slider_actions: actions };
  return { answer, measured };
}

// Where to look: the image holds both eyes' views side by side, each with its own cross.
const FIXATION = `<p class="fixation"><b>Where to look.</b> In a headset each eye sees its own
  half of the image, and the two crosses appear as one: <b>keep your eyes on that red cross</b>.
  On a monitor both halves are side by side: <b>keep your eyes on the red cross of the left
  half</b> (the left eye's view; the right half is the right eye's, leave it be). Keep looking at
  the cross the whole time, even during the black.</p>`;

const INSTRUCTIONS = {
  pair: (t, n) => `<p>You will see ${n} pairs of short animated sequences, the two of a pair separated by
    ${t.gap_s} s of black.</p>${FIXATION}<p>After each pair, answer whether the <b>first</b> was better, the
    <b>second</b> was better, or both looked the <b>same</b> (buttons, or keys 1, 2, 3).</p>`,
  ramp: (t, n) => `<p>First a reference sequence, then the same sequence at other quality levels, one after
    another (${n} in all, in two runs that each start from the reference), each shown for ${t.step_s} s and
    separated by black.</p>${FIXATION}<p>After each one, answer whether the quality <b>increased</b>,
    <b>decreased</b> or stayed the <b>same</b> compared with the sequence just before it (buttons, or keys
    1, 2, 3).</p>`,
  slider: (t) => `<p>First the reference sequence (${t.step_s} s), then the same sequence at a low
    quality level.</p>${FIXATION}<p>Lower (↓) or raise (↑) the level, or see the reference again (R), until
    the sequence looks the <b>same as the reference</b>; then choose it (Enter). Take your time.</p>`,
};

// A form field's name as the participant reads it ("age_range" -> "age range").
const fieldLabel = (name) => name.replace(/_/g, " ");

async function main() {
  try {
    let state = await getJSON("api/state");
    study.state = state;
    clipFps = state.clip_fps;
    fixation = state.fixation;
    const progress = () => {
      $("progress").textContent = `${state.participant} · ${state.test} test · ` +
        (state.next === null ? "done" : `trial ${state.next + 1} of ${state.trials}`);
    };
    progress();
    if (state.next === null) { study.phase = "done"; message(""); show("done", true); return; }
    message("");
    if (state.form_needed) {
      study.phase = "form";
      message("");
      const fields = $("form-fields");
      for (const [name, choices] of Object.entries(state.form)) {
        if (name === "consent") continue;
        const label = document.createElement("label");
        label.textContent = fieldLabel(name) + ":";
        const select = document.createElement("select");
        select.id = "form-" + name;
        select.innerHTML = `<option value="">choose…</option>` +
          choices.map((c) => `<option value="${c}">${c}</option>`).join("");
        label.appendChild(select);
        fields.appendChild(label);
      }
      show("form", true);
      await new Promise((resolve) => {
        $("form").addEventListener("submit", async (ev) => {
          ev.preventDefault();
          const form = {};
          for (const name of Object.keys(state.form)) {
            form[name] = name === "consent" ? ($("consent").checked ? "yes" : "no") : $("form-" + name).value;
          }
          // Said here, in plain words, before anything is sent: which questions are unanswered.
          const unanswered = Object.keys(state.form).filter((name) => name !== "consent" && !form[name]);
          for (const name of Object.keys(state.form)) {
            if (name !== "consent") $("form-" + name).classList.toggle("missing", unanswered.includes(name));
          }
          if (unanswered.length) {
            message(`Please choose an answer for: ${unanswered.map(fieldLabel).join(", ")} ` +
              "(“prefer not to say” is one of the choices).", true);
            return;
          }
          if (form.consent !== "yes") {
            message("Please tick the box to say you agree to take part (the study cannot start without it).", true);
            return;
          }
          try {
            await postJSON("api/form", form);
            show("form", false);
            resolve();
          } catch (err) {
            message(err.message, true);
          }
        });
      });
    }
    study.phase = "loading";
    await loadClips(state.clips);
    show("stage", true);  // the image area only from here: no empty black band above the form
    const frameMs = await measureFrames(30);
    study.frameMs = frameMs;
    message(`display: ${(1000 / frameMs).toFixed(1)} Hz`);
    $("instructions-title").textContent = `The ${state.test} test` + (state.resumed ? " (continued)" : "");
    $("instructions-text").innerHTML = INSTRUCTIONS[state.test](state.timings, state.trials);
    show("instructions", true);
    study.phase = "instructions";
    await waitClick([[$("start"), "start", "Enter"]]);
    show("instructions", false);
    while (state.next !== null) {
      const trial = await getJSON(`api/trial/${state.next}`);
      study.trial = trial;
      const result = trial.test === "slider" ? await sliderTrial(trial, frameMs) : await fixedTrial(trial, frameMs);
      message("saving…");
      const reply = await postJSON("api/answer", { index: trial.index, answer: result.answer,
        measured: result.measured });
      study.recorded.push(reply.recorded);
      state = reply.state;
      study.state = state;
      progress();
    }
    study.phase = "done";
    message("");
    show("done", true);
  } catch (err) {
    study.phase = "error";
    message(`error: ${err.message} — the answers given so far are saved; reload the page to continue`, true);
  }
}

main();
