// The surgeon seat's page: draws the frames the server streams, sends the person's keys and gamepad.
// window.dvrl exposes what the page measured (frames, key-to-frame latencies) for tests and benchmarks.
"use strict";
const token = new URLSearchParams(location.search).get("token") || "";
const MOVE_KEYS = new Set(["KeyA", "KeyD", "KeyS", "KeyW", "KeyF", "KeyR"]);
const SEAT_KEYS = new Set([...MOVE_KEYS, "Space", "ShiftLeft", "ShiftRight", "KeyI"]);
const DEAD_ZONE = 0.15;
const dvrl = window.dvrl = { frames: 0, latencies: [], status: null, role: null, connected: false, reconnect: true,
                             framesDrawnAt: [], sent: 0 };
const canvas = document.getElementById("screen");
const context = canvas.getContext("2d");
const $ = (id) => document.getElementById(id);
let socket = null, seq = 0, drawing = Promise.resolve();
const held = new Set();
const pending = new Map();  // seq of a move-key press -> when it was pressed

function connect() {
  const scheme = location.protocol === "https:" ? "wss:" : "ws:";
  socket = new WebSocket(`${scheme}//${location.host}/ws?token=${encodeURIComponent(token)}`);
  socket.binaryType = "arraybuffer";
  socket.onopen = () => { dvrl.connected = true; };
  socket.onclose = () => {
    dvrl.connected = false; dvrl.role = null;
    showBadge("lost", "disconnected"); $("banner").textContent = "Connection lost: reconnecting…";
    if (dvrl.reconnect) setTimeout(connect, 1000);
  };
  socket.onmessage = (event) => {
    if (typeof event.data === "string") {
      const message = JSON.parse(event.data);
      if (message.type === "role") { dvrl.role = message.role; showRole(); }
      return;
    }
    const view = new DataView(event.data);
    const length = view.getUint32(0);
    const status = JSON.parse(new TextDecoder().decode(new Uint8Array(event.data, 4, length)));
    const jpeg = new Blob([new Uint8Array(event.data, 4 + length)], { type: "image/jpeg" });
    drawing = drawing.then(() => createImageBitmap(jpeg)).then((bitmap) => {
      context.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
      bitmap.close();
      frameDrawn(status);
    }).catch(() => {});
  };
}

// Sends one message; returns its sequence number (the server tells which one the last step used).
function send(message) {
  if (!socket || socket.readyState !== WebSocket.OPEN) return null;
  message.seq = dvrl.sent = ++seq;
  socket.send(JSON.stringify(message));
  return seq;
}

// Public for disconnect tests: drop the connection (and optionally stop reconnecting).
dvrl.disconnect = (reconnect) => { dvrl.reconnect = reconnect; if (socket) socket.close(); };
dvrl.connect = () => { dvrl.reconnect = true; if (!socket || socket.readyState === WebSocket.CLOSED) connect(); };

function frameDrawn(status) {
  const now = performance.now();
  dvrl.frames += 1;
  dvrl.status = status;
  dvrl.framesDrawnAt.push(now);
  while (dvrl.framesDrawnAt.length && now - dvrl.framesDrawnAt[0] > 1000) dvrl.framesDrawnAt.shift();
  for (const [sent, at] of pending) {
    if (status.input_seq >= sent) { if (status.state === "running") dvrl.latencies.push(now - at); pending.delete(sent); }
    else if (now - at > 2000) pending.delete(sent);
  }
  showStatus(status);
}

function showBadge(kind, text) { const badge = $("badge"); badge.className = kind; badge.textContent = text; }

// Spectators see no controls they cannot use: Start, Reset and Record belong to the driver; "Take the seat" shows
// only while nobody drives it.
function showRole() {
  const driving = dvrl.role === "controller";
  $("role").textContent = driving ? "you drive the seat" : dvrl.role ? "you are watching (spectator)" : "";
  const free = dvrl.status ? !dvrl.status.controller : false;
  $("take").style.display = !driving && dvrl.role && free ? "" : "none";
  for (const id of ["start", "reset", "record"]) {
    $(id).disabled = !driving;
    $(id).style.display = dvrl.role && !driving ? "none" : "";
  }
}

const TASKS = {
  grasper: "You work the grasper (Large Needle Driver); a partner works the suction arm, which clears the blood " +
    "from the two cavities and so uncovers the debris (pins). Grasp each pin and bring it to the hand-off point " +
    "(the green marker and its post), where the first assistant takes it. The episode succeeds when the blood is " +
    "gone and every pin is delivered.",
  suction: "You work the suction arm (Suction & Irrigation); a partner works the grasper. Open the valve (Space) " +
    "with the tip at the blood's surface in each cavity: it draws only there. As the blood goes down it uncovers " +
    "pins, which your partner takes to the hand-off point. Keep out of your partner's way. The episode succeeds " +
    "when the blood is gone and every pin is delivered.",
};

// The top and side views: the phantom, its cavities, the hand-off point, both tips and the visible pins, drawn from
// the status (millimetres, world frame). The side view shows what the endoscope cannot: forward against up.
function drawViews(s) {
  const o = s.outline;
  if (!o) return;
  const low = o.workspace.low, high = o.workspace.high;
  const views = [
    { canvas: $("top"), h: 0, v: 1 },   // x right, y up
    { canvas: $("side"), h: 1, v: 2 },  // y right, z up
  ];
  const seatColour = s.seat === "grasper" ? "#ffd633" : "#59d9ff";
  const otherColour = s.seat === "grasper" ? "#59d9ff" : "#ffd633";
  for (const view of views) {
    const c = view.canvas.getContext("2d"), W = view.canvas.width, H = view.canvas.height;
    const pad = 8, scale = Math.min((W - 2 * pad) / (high[view.h] - low[view.h]), (H - 2 * pad) / (high[view.v] - low[view.v]));
    const px = (p) => pad + (p[view.h] - low[view.h]) * scale;
    const py = (p) => H - pad - (p[view.v] - low[view.v]) * scale;
    c.fillStyle = "#15171c"; c.fillRect(0, 0, W, H);
    c.strokeStyle = "#444"; c.strokeRect(pad, pad, (high[view.h] - low[view.h]) * scale, (high[view.v] - low[view.v]) * scale);
    const ph = o.phantom;
    c.fillStyle = "#d9a58f";
    if (view.v === 1) {
      c.fillRect(px([ph.centre[0] - ph.half[0], 0]), py([0, ph.centre[1] + ph.half[1]]), 2 * ph.half[0] * scale, 2 * ph.half[1] * scale);
      for (const cav of o.cavities) {
        c.beginPath(); c.arc(px(cav.centre), py(cav.centre), cav.radius * scale, 0, 2 * Math.PI);
        c.fillStyle = "#b07a68"; c.fill();
      }
    } else {
      c.fillRect(px([0, ph.centre[1] - ph.half[1]]), py([0, 0, ph.top]), 2 * ph.half[1] * scale, (ph.top - ph.table) * scale);
      for (const cav of o.cavities) {
        c.fillStyle = "#b07a68";
        c.fillRect(px([0, cav.centre[1] - cav.radius]), py([0, 0, ph.top]), 2 * cav.radius * scale, (ph.top - cav.floor) * scale);
      }
    }
    const dot = (p, r, colour, ring) => {
      c.beginPath(); c.arc(px(p), py(p), r, 0, 2 * Math.PI);
      if (ring) { c.strokeStyle = colour; c.lineWidth = 2; c.stroke(); c.lineWidth = 1; } else { c.fillStyle = colour; c.fill(); }
    };
    dot(o.handoff, 6, "#1ae65a", true);
    for (const pin of s.pins || []) dot(pin.mm, 3, pin.held ? "#ffffff" : "#e0e0e0");
    const other = s.tips_mm[s.seat === "grasper" ? "suction" : "grasper"];
    dot(other, 4, otherColour);
    dot(s.tips_mm[s.seat], 5, seatColour);
    if (view.v === 2) {  // the drop line: the tip's height over what lies below it
      const tip = s.tips_mm[s.seat], below = [tip[0], tip[1], tip[2] - s.cues.tip_height_mm];
      c.strokeStyle = seatColour; c.setLineDash([3, 3]); c.beginPath();
      c.moveTo(px(tip), py(tip)); c.lineTo(px(below), py(below)); c.stroke(); c.setLineDash([]);
    }
  }
}

function showCues(s) {
  const q = s.cues;
  $("height").textContent = `${q.tip_height_mm.toFixed(1)} mm above the surface below`;
  let cue = "";
  if (s.seat === "grasper") {
    $("tool-label").textContent = "Jaw";
    $("reach-label").textContent = q.holding ? "Holding a pin" : "Nearest pin";
    $("tool").textContent = s.jaw > 0.5 ? "open" : "closed";
    if (q.holding) {
      $("reach").textContent = `${q.handoff_mm.toFixed(1)} mm to the hand-off (delivered within 3 mm)`;
      $("reach-row").className = "good";
      cue = `<span class="holding">Holding a pin: ${q.handoff_mm.toFixed(0)} mm to the hand-off</span>`;
    } else if (q.pin_mm === null) {
      $("reach").textContent = "none uncovered yet"; $("reach-row").className = "";
    } else if (q.in_reach) {
      $("reach").textContent = `IN REACH (${q.pin_mm.toFixed(1)} mm): close the jaw (Space)`;
      $("reach-row").className = "good";
      cue = `<span class="reach">Pin in reach: close the jaw (Space)</span>`;
    } else {
      $("reach").textContent = `${q.pin_mm.toFixed(1)} mm from the jaws (in reach within 3 mm)`;
      $("reach-row").className = "";
    }
  } else {
    $("tool-label").textContent = "Valve";
    $("reach-label").textContent = "Blood surface";
    $("tool").textContent = (q.irrigating ? "IRRIGATING" : s.valve_open ? "open" : "closed") +
      (q.drawing ? ", drawing blood" : "") +
      (s.saline_used_ml !== undefined ? `; saline ${s.saline_used_ml.toFixed(1)} ml used (hold I)` : "");
    if (q.irrigating) cue = `<span class="holding">Irrigating: saline breaks the clots up; then draw the mix</span>`;
    if (q.spill) cue = `<span class="blocked">Spill: a cavity overflowed, the pins around it are hidden a while</span>`;
    $("reach").textContent = q.above_blood_mm === null ? "not over blood"
      : q.above_blood_mm > 0 ? `${q.above_blood_mm.toFixed(1)} mm above it (draws within 2 mm)` : "tip in the blood";
    $("reach-row").className = q.drawing ? "good" : "";
  }
  $("blocked").textContent = q.blocked ? "IN THE WAY: your move was refused" : "clear";
  $("blocked-row").className = q.blocked ? "warn" : "";
  if (q.blocked) cue = `<span class="blocked">Blocked by the other instrument: move around it</span>`;
  $("cue").innerHTML = s.state === "running" ? cue : "";
}

function showStatus(s) {
  const blood = s.blood_ml.map((ml, i) => `<span class="bar" style="width:${s.blood_text[i] === "clear" ? 0 : Math.min(60, 5 * ml)}px"></span>` +
    (s.blood_text[i] === "clear" ? "clear" : ml.toFixed(1)));
  $("blood").innerHTML = blood.join("<br>");
  $("found").textContent = `${s.debris_found} / ${s.debris_total}`;
  $("delivered").textContent = `${s.debris_delivered} / ${s.debris_total}`;
  $("time").textContent = `${s.time_s.toFixed(1)} s of ${s.max_time_s.toFixed(0)} s (episode ${s.episode}, seed ${s.seed})`;
  $("seat").textContent = s.seat_tool;
  $("task").textContent = TASKS[s.seat] || "";
  showCues(s);
  drawViews(s);
  showRole();
  $("partner").textContent = `${s.partner} (${s.seat === "grasper" ? "suction arm" : "grasper arm"})`;
  $("recording").textContent = s.recording
    ? `on: ${s.recorded_episodes} episode(s) kept, this one ${s.recorded_steps} steps`
    : "off (Record starts with the next episode)";
  $("record").textContent = s.recording ? "Stop recording" : "Record";
  $("saved").textContent = s.saved.length ? "Saved: " + s.saved.map((d) => d.id
    ? `${d.id} (${d.episodes} episodes, ${d.successes} succeeded)` : `failed: ${d.error}`).join("; ") : "";
  const lat = dvrl.latencies.slice(-20).sort((a, b) => a - b);
  $("stream").textContent = `${dvrl.framesDrawnAt.length} frames/s` +
    (lat.length ? `, key to frame ${lat[lat.length >> 1].toFixed(0)} ms` : "");
  $("dropped").textContent = s.dropped_messages ? `${s.dropped_messages} (last: ${s.last_drop})` : "0";
  let banner = "";
  if (s.state === "error") { showBadge("error", "error"); banner = s.error; }
  else if (s.state === "waiting") {
    showBadge("", "ready");
    banner = dvrl.role === "controller" ? "Press Start (or Enter) to begin" : "Waiting for the surgeon to start";
  } else if (s.state === "over") {
    showBadge(s.success ? "success" : "over", s.success ? "SUCCESS" : "time is up");
    banner = s.success ? "SUCCESS: the field is clear. Reset for another episode." : "Time is up. Reset to try again.";
  } else if (s.teleop_lost) {
    showBadge("lost", "seat lost");
    banner = "No input from the surgeon's page: the arm holds still";
  } else showBadge("running", "running");
  $("banner").textContent = banner;
}

document.addEventListener("keydown", (event) => {
  if (event.code === "Enter") { send({ type: "start" }); event.preventDefault(); return; }
  if (!SEAT_KEYS.has(event.code)) return;
  event.preventDefault();  // SPACE must not scroll the page
  if (event.repeat || held.has(event.code)) return;
  held.add(event.code);
  const sent = send({ type: "key", code: event.code, down: true });
  if (sent !== null && MOVE_KEYS.has(event.code)) pending.set(sent, performance.now());
});
document.addEventListener("keyup", (event) => {
  if (!SEAT_KEYS.has(event.code)) return;
  held.delete(event.code);
  send({ type: "key", code: event.code, down: false });
});
window.addEventListener("blur", () => {  // a key released while the page had no focus would stay held
  for (const code of held) send({ type: "key", code, down: false });
  held.clear();
});

$("start").onclick = () => send({ type: "start" });
$("reset").onclick = () => send({ type: "reset" });
$("record").onclick = () => send({ type: "record", on: !(dvrl.status && dvrl.status.recording) });
$("take").onclick = () => send({ type: "take" });

// Gamepad API: sticks move, A toggles the jaw, Start starts. Sent when something changes.
let lastPad = { axes: "0,0,0", toggle: false, start: false };
function shape(value) { return Math.abs(value) < DEAD_ZONE ? 0 : Math.max(-1, Math.min(1, value)); }
function pollGamepad() {
  const pads = navigator.getGamepads ? Array.from(navigator.getGamepads()).filter((p) => p) : [];
  if (pads.length) {
    const pad = pads[0];
    const axes = [shape(pad.axes[0] || 0), shape(-(pad.axes[1] || 0)), shape(-(pad.axes[3] || 0))];
    const toggle = !!(pad.buttons[0] && pad.buttons[0].pressed);
    const start = !!(pad.buttons[9] && pad.buttons[9].pressed);
    const key = axes.join(",");
    if (key !== lastPad.axes || (toggle && !lastPad.toggle)) {
      const sent = send({ type: "gamepad", axes, toggle: toggle && !lastPad.toggle });
      if (sent !== null && key !== lastPad.axes && axes.some((v) => v !== 0)) pending.set(sent, performance.now());
    }
    if (start && !lastPad.start) send({ type: "start" });
    lastPad = { axes: key, toggle, start };
  } else if (lastPad.axes !== "0,0,0") {
    send({ type: "gamepad", axes: [0, 0, 0], toggle: false });
    lastPad = { axes: "0,0,0", toggle: false, start: false };
  }
  requestAnimationFrame(pollGamepad);
}
requestAnimationFrame(pollGamepad);
setInterval(() => send({ type: "ping" }), 200);  // the seat counts a silent page as gone
connect();
