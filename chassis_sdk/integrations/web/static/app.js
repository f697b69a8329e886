// The chassis-sdk dashboard: shows the device live and drives it by hand.
//
// Safety is the server's (every drive message is one command under the deadman); the
// page's part: while a control is held it sends the current command every SEND_MS, and
// the moment the control is let go (the stick, the key, the gamepad's enable button),
// the page is hidden, the window loses focus or the gamepad goes away or stalls, it
// sends "stop" at once. A frozen tab sends nothing, so the deadman stops the robot.
"use strict";

const SEND_MS = 50; // 20 Hz
const SPEED_WINDOW_S = 20;
const $ = (id) => document.getElementById(id);

const state = {
  ws: null,
  hello: null,
  retry: 250,
  joy: null, // {x, y} in the unit circle while the stick is held
  keys: new Set(),
  pad: { index: null, stamp: null, since: 0, stale: false, enabled: false },
  driving: false,
  command: [0, 0],
  speed: { t: [], linCmd: [], linMeas: [], angCmd: [], angMeas: [] },
  path: { x: [], y: [] },
  plots: {},
  led: null, // as the device last reported it (null: not known yet)
  buzzer: null,
};
window.chassisDashboard = state; // for the curious (and the tests)

// --- the socket ------------------------------------------------------------------------

function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const ws = new WebSocket(`${scheme}://${location.host}/ws`);
  state.ws = ws;
  ws.onopen = () => { state.retry = 250; setPill("socket", "connected", "good"); };
  ws.onmessage = (event) => {
    let message;
    try { message = JSON.parse(event.data); } catch { return; }
    if (message.type === "hello") onHello(message);
    else if (message.type === "state") onState(message);
  };
  ws.onclose = () => {
    state.ws = null;
    state.driving = false;
    setPill("socket", "disconnected: retrying", "bad");
    setTimeout(connect, state.retry);
    state.retry = Math.min(state.retry * 2, 4000);
  };
}

function send(message) {
  const ws = state.ws;
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(message));
}

// --- what the server says --------------------------------------------------------------

function offers(action) {
  return Boolean(state.hello && state.hello.actions.includes(action));
}

function onHello(hello) {
  state.hello = hello;
  $("title").textContent = `chassis-sdk ${hello.device}`;
  document.title = `${hello.device} ${hello.port}: chassis-sdk`;
  const mode = hello.stop_only ? " · stop only: the page limit is reached" : hello.read_only ? " · read-only" : "";
  $("mode").textContent = `${hello.port}${mode} · deadman ${hello.command_timeout} s`;
  for (const id of ["release", "clear_faults", "led", "buzzer"]) $(id).hidden = !offers(id);
  // Without an e-stop (a board), E-STOP stops the robot and nothing more: say so on it.
  const note = `a ${hello.device} has no e-stop: E-STOP only stops it`;
  $("estop").textContent = hello.estop === false ? "E-STOP (stops only)" : "E-STOP";
  $("estop").title = hello.estop === false ? note : "engage the device's e-stop";
  $("estop-note").textContent = note;
  $("estop-note").hidden = hello.estop !== false;
  $("drive").hidden = !offers("drive");
  $("pad-enable").textContent = `buttons[${hello.gamepad.enable_button}]`;
  state.path = { x: [], y: [] };
  for (const [x, y] of hello.path) { state.path.x.push(x); state.path.y.push(y); }
  $("events").replaceChildren();
  for (const event of hello.events) addEvent(event);
}

function fixed(value, digits = 2) {
  return typeof value === "number" && Number.isFinite(value) ? value.toFixed(digits) : "-";
}

function onState(s) {
  const link = s.link.state;
  setPill("link", link.toLowerCase(), link === "CONNECTED" ? "good" : "bad");
  $("age").textContent = s.link.age == null ? "no frame yet" : `last frame ${(s.link.age * 1000).toFixed(0)} ms ago`;
  const cmd = s.commanded || [0, 0];
  const odo = s.odometry;
  const measured = measuredSpeed(s.streams, odo);
  $("lin-cmd").textContent = fixed(cmd[0]);
  $("ang-cmd").textContent = fixed(cmd[1]);
  $("lin-meas").textContent = fixed(measured[0]);
  $("ang-meas").textContent = fixed(measured[1]);
  $("estop-banner").hidden = !s.estop;
  $("refused").textContent = String(s.refused);
  for (const note of s.notes || []) {
    if (note.refused) $("refusal").textContent = `latest: ${note.refused}`;
    if (note.done) $("done").textContent = `done: ${note.done}`;
  }
  showOutputs(s.outputs || {});
  for (const event of s.events || []) addEvent(event);
  if (odo) {
    $("pose").textContent = `x ${fixed(odo.x)} m, y ${fixed(odo.y)} m, heading ${fixed(odo.heading * 180 / Math.PI, 0)}°`;
    const n = state.path.x.length;
    if (!n || Math.hypot(odo.x - state.path.x[n - 1], odo.y - state.path.y[n - 1]) >= 0.02) {
      state.path.x.push(odo.x); state.path.y.push(odo.y);
      if (state.path.x.length > 2000) { state.path.x.shift(); state.path.y.shift(); }
    }
  }
  showStatus(s.streams, s.faults || []);
  showCharge(s.battery);
  showStreams(s.streams);
  const sp = state.speed;
  sp.t.push(s.time); sp.linCmd.push(cmd[0]); sp.angCmd.push(cmd[1]);
  sp.linMeas.push(measured[0]); sp.angMeas.push(measured[1]);
  while (sp.t.length && sp.t[0] < s.time - SPEED_WINDOW_S) {
    for (const key of Object.keys(sp)) sp[key].shift();
  }
  drawPlots();
}

function measuredSpeed(streams, odo) {
  const source = streams.telemetry || streams.velocity || odo;
  return source ? [source.linear, source.angular] : [null, null];
}

function setPill(id, text, kind) {
  const el = $(id);
  el.textContent = id === "link" ? `link ${text}` : text;
  el.className = `pill ${kind}`;
}

function addEvent(event) {
  const li = document.createElement("li");
  const when = new Date(event.time * 1000).toLocaleTimeString();
  li.textContent = `${when}  ${event.text}`;
  const list = $("events");
  list.prepend(li);
  while (list.children.length > 50) list.lastChild.remove();
}

function flagsOf(value) {
  if (!value) return []; // "" when none is set
  return String(value).split("|");
}

// The state of charge (a device given battery=BatteryModel(...)): the number and a bar
// coloured by level, "—" while it is not known; nothing without a model.
function showCharge(charge) {
  const box = $("charge");
  box.hidden = !charge;
  if (!charge) return;
  const known = typeof charge.percentage === "number";
  const level = known && charge.level ? charge.level.toLowerCase() : "unknown";
  box.dataset.level = level;
  $("charge-text").textContent = !known ? "—"
    : `${charge.percentage.toFixed(0)} %${level === "ok" ? "" : ` ${charge.level}`}`;
  $("charge-bar").style.width = known ? `${Math.min(100, Math.max(0, charge.percentage))}%` : "0%";
}

// The LED and buzzer as the device reported them (the reply to the last switch).
function showOutputs(outputs) {
  for (const id of ["led", "buzzer"]) {
    const on = typeof outputs[id] === "boolean" ? outputs[id] : null;
    state[id] = on;
    const button = $(id);
    button.setAttribute("aria-pressed", String(on === true));
    button.textContent = `${id === "led" ? "LED" : "buzzer"} ${on === null ? "?" : on ? "on" : "off"}`;
  }
}

// A flag that stops the wheels (the server's `faults`) is an alarm; any other
// (REMOTE_OFFLINE: no remote control, normal under host control) is information.
function showStatus(streams, faults) {
  const t = streams.telemetry;
  const battery = streams.battery || t;
  $("battery").textContent = battery ? `${fixed(battery.voltage, 1)} V` : "-";
  const flags = $("flags");
  if (t) {
    const names = flagsOf(t.status);
    flags.replaceChildren(...(names.length ? names : ["OK"]).map((name) => {
      const span = document.createElement("span");
      span.className = !names.length ? "flag ok" : faults.includes(name) ? "flag bad" : "flag info";
      span.textContent = name;
      span.title = faults.includes(name) ? "stops the wheels" : "information";
      return span;
    }));
    if (t.docking && t.docking !== "NONE" && t.docking !== 0) {
      const span = document.createElement("span");
      span.className = "flag ok";
      span.textContent = `docking ${t.docking}`;
      flags.append(span);
    }
    showWheels(t.wheels, streams.power && streams.power.currents);
  } else {
    flags.textContent = "-";
  }
  const imu = streams.imu;
  if (imu) {
    const v = (vec, digits) => `${fixed(vec.x, digits)}, ${fixed(vec.y, digits)}, ${fixed(vec.z, digits)}`;
    $("imu").innerHTML = "";
    const table = document.createElement("table");
    table.className = "numbers";
    for (const [name, vec, unit, digits] of [
      ["accel", imu.accel, "g", 3], ["gyro", imu.gyro, "°/s", 1], ["mag", imu.mag, "counts", 0],
    ]) {
      const row = table.insertRow();
      row.insertCell().textContent = `IMU ${name}`;
      row.insertCell().textContent = v(vec, digits);
      row.insertCell().textContent = unit;
    }
    $("imu").append(table);
  }
}

function showWheels(wheels, currents) {
  if (!wheels) return;
  const max = state.hello ? state.hello.max_linear : 0.5;
  const table = document.createElement("table");
  table.className = "bars";
  for (const [name, speed] of Object.entries(wheels)) {
    const row = table.insertRow();
    row.insertCell().textContent = name.replace("_", " ");
    const track = row.insertCell();
    track.className = "track";
    const bar = document.createElement("div");
    bar.className = "bar";
    bar.style.width = `${Math.min(100, Math.abs(speed) / max * 100)}%`;
    if (speed < 0) bar.style.background = "#b26a00";
    track.append(bar);
    row.insertCell().textContent = `${fixed(speed)} m/s`;
    if (currents && name in currents) row.insertCell().textContent = `${fixed(currents[name], 1)} A`;
  }
  $("wheels").replaceChildren(table);
}

function flatten(prefix, value, out) {
  if (value && typeof value === "object" && !Array.isArray(value)) {
    for (const [k, v] of Object.entries(value)) flatten(prefix ? `${prefix}.${k}` : k, v, out);
  } else if (prefix !== "timestamp" && prefix !== "raw") {
    out.push([prefix, value]);
  }
}

function showStreams(streams) {
  const tables = [];
  for (const [name, reading] of Object.entries(streams)) {
    const rows = [];
    flatten("", reading, rows);
    const table = document.createElement("table");
    table.createCaption().textContent = name;
    for (const [key, value] of rows) {
      const row = table.insertRow();
      row.insertCell().textContent = key;
      row.insertCell().textContent = typeof value === "number" && !Number.isInteger(value) ? value.toFixed(3) : String(value);
    }
    tables.push(table);
  }
  $("streams").replaceChildren(...tables);
}

// --- plots (uPlot) ---------------------------------------------------------------------

function plotWidth(id) {
  return Math.max(260, $(id).parentElement.clientWidth - 24);
}

function speedRange(_u, min, max) {
  const h = state.hello;
  const limit = h ? Math.max(h.max_linear, h.max_angular) : 1;
  const lo = Number.isFinite(min) ? Math.min(min, -limit) : -limit;
  const hi = Number.isFinite(max) ? Math.max(max, limit) : limit;
  return [lo, hi];
}

function drawPlots() {
  if (typeof uPlot === "undefined") return;
  const sp = state.speed;
  const speedData = [sp.t, sp.linCmd, sp.linMeas, sp.angCmd, sp.angMeas];
  if (!state.plots.speed) {
    state.plots.speed = new uPlot({
      width: plotWidth("speed-plot"), height: 180, legend: { show: true, live: false },
      // Before anything moves every value is 0, where uPlot's default range is 0-100:
      // the axis spans at least the page's limits.
      scales: { x: { time: true }, y: { range: speedRange } },
      series: [
        {},
        { label: "linear cmd", stroke: "#1769aa", dash: [6, 4], width: 1.5 },
        { label: "linear", stroke: "#1769aa", width: 2 },
        { label: "angular cmd", stroke: "#c2185b", dash: [6, 4], width: 1.5 },
        { label: "angular", stroke: "#c2185b", width: 2 },
      ],
      axes: [{}, { size: 44 }],
    }, speedData, $("speed-plot"));
  } else {
    state.plots.speed.setData(speedData);
  }
  const p = state.path;
  if (!p.x.length) return;
  // One metre is as long across as up and down: both ranges span the larger extent.
  const range = () => {
    const xs = p.x, ys = p.y;
    const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
    const half = Math.max(0.5, (x1 - x0) / 2, (y1 - y0) / 2) * 1.15;
    return { x: [(x0 + x1) / 2 - half, (x0 + x1) / 2 + half], y: [(y0 + y1) / 2 - half, (y0 + y1) / 2 + half] };
  };
  // The path with y to the left (the robot's frame): the plot's x is -y, its y is x.
  const pathData = [null, [p.y.map((v) => -v), p.x]];
  if (!state.plots.path) {
    const size = Math.min(plotWidth("path-plot"), 320);
    state.plots.path = new uPlot({
      mode: 2, width: size, height: size, legend: { show: false }, cursor: { show: false },
      scales: {
        x: { time: false, range: () => { const r = range(); return [-r.y[1], -r.y[0]]; } },
        y: { range: () => range().x },
      },
      series: [{}, { label: "path", stroke: "#1f8f4e", width: 2, paths: uPlot.paths.linear(), points: { show: false } }],
      axes: [{ label: "← left  (m)  right →", size: 36 }, { label: "forward (m)", size: 44 }],
    }, pathData, $("path-plot"));
  } else {
    state.plots.path.setData(pathData);
  }
}

// --- driving ---------------------------------------------------------------------------

function scale() {
  return Number($("scale").value);
}

const KEYS = {
  KeyW: [1, 0], ArrowUp: [1, 0], KeyS: [-1, 0], ArrowDown: [-1, 0],
  KeyA: [0, 1], ArrowLeft: [0, 1], KeyD: [0, -1], ArrowRight: [0, -1],
};

function fromKeys() {
  if (!state.keys.size) return null;
  let lin = 0, ang = 0;
  for (const code of state.keys) { lin += KEYS[code][0]; ang += KEYS[code][1]; }
  return [Math.sign(lin), Math.sign(ang)];
}

function deadzone(value, zone) {
  if (!Number.isFinite(value) || Math.abs(value) > 1.0001) return null; // out of range: no command
  return Math.abs(value) < zone ? 0 : value;
}

function fromPad() {
  const pad = state.pad;
  const map = state.hello ? state.hello.gamepad : null;
  pad.enabled = false;
  if (!map || !navigator.getGamepads) return null;
  const pads = Array.from(navigator.getGamepads() || []).filter((g) => g && g.connected);
  const gp = pads.find((g) => g.index === pad.index) || pads[0];
  if (!gp) { pad.index = null; $("pad").textContent = "none"; return null; }
  pad.index = gp.index;
  const now = performance.now();
  if (gp.timestamp !== pad.stamp) { pad.stamp = gp.timestamp; pad.since = now; }
  pad.stale = now - pad.since > map.stale_after * 1000;
  const button = gp.buttons[map.enable_button];
  const held = Boolean(button && button.pressed);
  const lin = deadzone(-(gp.axes[map.linear_axis] ?? NaN), map.deadzone);
  const ang = deadzone(-(gp.axes[map.angular_axis] ?? NaN), map.deadzone);
  const what = pad.stale ? "stale: stopped" : held ? "enabled" : "hold enable to drive";
  $("pad").textContent = `${gp.id.slice(0, 40)} (${what})`;
  if (!held || pad.stale || lin === null || ang === null) return null;
  pad.enabled = true;
  return [lin * map.scale_linear, ang * map.scale_angular];
}

function currentCommand() {
  if (!offers("drive")) return null;
  let unit = null;
  if (state.joy) unit = [-state.joy.y, -state.joy.x];
  else unit = fromKeys() || fromPad();
  if (!unit) return null;
  const h = state.hello, k = scale();
  const lin = unit[0] * h.max_linear * k;
  const ang = unit[1] * h.max_angular * k;
  // Towards zero: a full stick must never round past the limit (it would be refused).
  return [Math.trunc(lin * 1000) / 1000, Math.trunc(ang * 1000) / 1000];
}

function tick() {
  const command = currentCommand();
  if (command) {
    send({ type: "drive", linear: command[0], angular: command[1], t: performance.now() });
    state.driving = true;
    state.command = command;
  } else if (state.driving) {
    send({ type: "stop" });
    state.driving = false;
    state.command = [0, 0];
  }
  $("command").textContent = `${fixed(state.command[0])} m/s, ${fixed(state.command[1])} rad/s`;
}

function letGo() {
  state.joy = null;
  state.keys.clear();
  placeKnob(0, 0);
  $("joystick").classList.remove("active");
  if (state.driving) tick();
}

function stopNow() {
  letGo();
  send({ type: "stop" });
  state.driving = false;
  state.command = [0, 0];
  tick();
}

// The on-screen joystick: pointer events, so a mouse, a pen and a finger all work.
function placeKnob(x, y) {
  const knob = $("knob");
  const r = $("joystick").clientWidth / 2 - knob.clientWidth / 2;
  knob.style.transform = `translate(${x * r}px, ${y * r}px)`;
}

function joyAt(event) {
  const box = $("joystick").getBoundingClientRect();
  const r = box.width / 2;
  let x = (event.clientX - box.left - r) / r, y = (event.clientY - box.top - r) / r;
  const n = Math.hypot(x, y);
  if (n > 1) { x /= n; y /= n; }
  state.joy = { x, y };
  placeKnob(x, y);
}

function setUp() {
  const joy = $("joystick");
  joy.addEventListener("pointerdown", (event) => {
    if (!offers("drive")) return;
    joy.setPointerCapture(event.pointerId);
    joy.classList.add("active");
    joyAt(event);
    tick();
  });
  joy.addEventListener("pointermove", (event) => { if (state.joy) joyAt(event); });
  for (const name of ["pointerup", "pointercancel", "lostpointercapture"]) {
    joy.addEventListener(name, letGo);
  }
  window.addEventListener("keydown", (event) => {
    if (event.code === "Space") { event.preventDefault(); stopNow(); return; }
    if (event.code in KEYS && offers("drive")) {
      event.preventDefault();
      if (!state.keys.has(event.code)) { state.keys.add(event.code); tick(); }
    }
  });
  window.addEventListener("keyup", (event) => {
    if (state.keys.delete(event.code)) tick();
  });
  window.addEventListener("blur", letGo); // a key held while focus leaves never comes up
  document.addEventListener("visibilitychange", () => { if (document.hidden) stopNow(); });
  window.addEventListener("pagehide", stopNow);
  window.addEventListener("gamepaddisconnected", () => { state.pad.index = null; tick(); });
  $("stop").addEventListener("click", stopNow);
  // E-STOP, then the page's neutral: it has let go of its controls, so once the e-stop
  // is released it drives again on a new press (the motion core owes it a neutral).
  $("estop").addEventListener("click", () => { letGo(); send({ type: "estop" }); send({ type: "stop" }); state.driving = false; });
  $("release").addEventListener("click", () => send({ type: "release" }));
  $("clear_faults").addEventListener("click", () => send({ type: "clear_faults" }));
  for (const id of ["led", "buzzer"]) {
    // Switches to the other state than the one reported; the button shows the
    // device's answer when it comes (showOutputs), not what was asked.
    $(id).addEventListener("click", () => send({ type: id, on: state[id] !== true }));
  }
  $("scale").addEventListener("input", () => { $("scale-out").textContent = `${Math.round(scale() * 100)} %`; });
  setInterval(tick, SEND_MS);
  connect();
}

setUp();
