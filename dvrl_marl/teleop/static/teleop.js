// The surgeon seat's page: draws the frames the server streams, sends the person's keys and gamepad.
// window.dvrl exposes what the page measured (frames, key-to-frame latencies) for tests and benchmarks.
"use strict";
const token = new URLSearchParams(location.search).get("token") || "";
const MOVE_KEYS = new Set(["KeyA", "KeyD", "KeyS", "KeyW", "KeyF", "KeyR"]);
const SEAT_KEYS = new Set([...MOVE_KEYS, "Space", "ShiftLeft", "ShiftRight"]);
const DEAD_ZONE = 0.15;
const dvrl = window.dvrl = { frames: 0, latencies: [], status: null, role: null, connected: false, reconnect: true,
                             framesDrawnAt: [] };
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
  message.seq = ++seq;
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

function showRole() {
  const driving = dvrl.role === "controller";
  $("role").textContent = driving ? "you drive the seat" : "you are watching (spectator)";
  $("take").style.display = driving ? "none" : "";
  for (const id of ["start", "reset", "record"]) $(id).disabled = !driving;
}

function showStatus(s) {
  const blood = s.blood_ml.map((ml) => `<span class="bar" style="width:${Math.min(60, 5 * ml)}px"></span>${ml.toFixed(1)}`);
  $("blood").innerHTML = blood.join("<br>");
  $("found").textContent = `${s.debris_found} / ${s.debris_total}`;
  $("delivered").textContent = `${s.debris_delivered} / ${s.debris_total}`;
  $("time").textContent = `${s.time_s.toFixed(1)} s of ${s.max_time_s.toFixed(0)} s (episode ${s.episode}, seed ${s.seed})`;
  $("seat").textContent = s.seat_tool;
  $("partner").textContent = `${s.partner} (${s.seat === "grasper" ? "suction arm" : "grasper arm"})`;
  $("tool").textContent = s.seat === "grasper" ? (s.jaw > 0.5 ? "jaw open" : "jaw closed")
                                               : (s.valve_open ? "valve open" : "valve closed");
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
