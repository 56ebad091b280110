// The page: loads Pyodide and c20sim from this site, then draws the drive and sends what the user does to the
// page's Python (c20sim.browser.page), whose every operation is a row of the control API's route table.
import { loadPyodide } from "./pyodide/pyodide.mjs";
import { serveOn, FORMATS } from "./serial.js";

const $ = (id) => document.getElementById(id);
const HISTORY = 600; // plot points kept
const REFRESH_MS = 100; // the real-time clock's refresh

let py = null;
let mod = null;
let page = null;
let info = null;
let history = [];
let lastSeq = 0;
let frameRows = [];
let timer = null;
let serial = null;

/** What the page's scripts, and its tests, can reach. */
const c20 = (window.c20 = {
  ready: null,
  loadMs: null,
  page: () => page,
  python: () => py,
  serveOn: (port, opts) => serveOn(port, page, opts),
});

function status(text, kind = "") {
  const el = $("status");
  el.textContent = text;
  el.className = kind;
}

/** The last line of a Python exception's message: the one line the user needs, never the traceback. */
function oneLine(err) {
  const lines = String(err && err.message ? err.message : err).trim().split("\n");
  return lines[lines.length - 1].replace(/^[\w.]+(Error|Exception): /, "");
}

function call(name, params = {}, body = {}) {
  const answer = JSON.parse(page.call(name, JSON.stringify(params), JSON.stringify(body)));
  if (answer && answer.error) throw new Error(answer.error);
  return answer;
}

function note(text, error = false) {
  const el = $("key-note");
  el.textContent = text;
  el.className = error ? "note error" : "note";
}

// --- Start: Pyodide, the package, the drive.

async function boot() {
  const t0 = performance.now();
  py = await loadPyodide({ indexURL: new URL("./pyodide/", location.href).href });
  status("loading c20sim…");
  const zip = await (await fetch("c20sim.zip")).arrayBuffer();
  py.unpackArchive(zip, "zip", { extractDir: "/home/pyodide/c20sim-site" });
  py.runPython("import sys; sys.path.insert(0, '/home/pyodide/c20sim-site')");
  mod = py.pyimport("c20sim.browser.page");
  start({});
  c20.loadMs = performance.now() - t0;
  status(`ready (${(c20.loadMs / 1000).toFixed(1)} s to load)`, "ok");
}

function start({ name = "", text = "", filename = "" }) {
  const clock = $("clock").value;
  let fresh;
  try {
    fresh = mod.start.callKwargs({ name, text, filename, clock });
  } catch (err) {
    $("profile-note").textContent = oneLine(err); // names the file and the key
    $("profile-note").className = "error";
    return false;
  }
  if (serial) serial.close();
  serial = null;
  if (page) { page.close(); page.destroy(); }
  page = fresh;
  info = JSON.parse(page.info());
  history = [];
  lastSeq = 0;
  frameRows = [];
  $("frames").textContent = "";
  $("exchanges").textContent = "";
  $("profile-note").textContent = `${info.source}${info.source === info.profile ? "" : ` (${info.profile})`}`;
  $("profile-note").className = "";
  fillControls();
  $("time-controls").style.display = info.clock === "virtual" ? "" : "none";
  if (timer) clearInterval(timer);
  timer = info.clock === "realtime" ? setInterval(tick, REFRESH_MS) : null;
  sample();
  refresh();
  return true;
}

function fillControls() {
  const profile = $("profile");
  if (!profile.options.length) {
    for (const name of info.profiles) profile.add(new Option(name, name));
  }
  if (info.profiles.includes(info.source)) profile.value = info.source;
  $("address").textContent = `at address ${info.address}`;
  const cause = $("cause");
  cause.textContent = "";
  for (const name of info.causes) cause.add(new Option(name.replaceAll("_", " "), name));
  const pick = $("pick");
  pick.length = 1;
  for (const row of info.sheet_frames) pick.add(new Option(`${row.operation}: ${row.request}`, row.request));
  const format = $("format");
  if (!format.options.length) for (const name of Object.keys(FORMATS)) format.add(new Option(name, name));
  const form = $("conditions-form");
  form.textContent = "";
  const state = JSON.parse(page.state()).drive;
  for (const [name, c] of Object.entries(info.conditions)) {
    if (c.low === null) continue; // hall_fault: a word, set from the fault list
    const label = document.createElement("label");
    // the condition's name less its unit suffix (supply_v, load_torque_nm), then the unit as the profile says it
    const words = c.unit ? name.replace(/_(v|nm|kg_m2|c)$/, "") : name;
    label.textContent = `${words.replaceAll("_", " ")}${c.unit ? ` (${c.unit})` : ""}`;
    const input = document.createElement("input");
    input.type = "number";
    input.step = "any";
    input.min = c.low;
    input.max = c.high;
    input.name = name;
    input.title = c.help || `${c.low} to ${c.high}`;
    const value = state.conditions[name];
    input.value = value === null || value === undefined ? "" : +(+value).toFixed(4);
    input.addEventListener("change", () => setCondition(name, input));
    label.append(input);
    form.append(label);
  }
}

// --- The panel.

function sample() {
  const point = JSON.parse(page.sample());
  history.push(point);
  if (history.length > HISTORY) history.splice(0, history.length - HISTORY);
}

function tick() {
  sample();
  refresh();
}

function fmt(value, digits) {
  return value === null || value === undefined ? "-" : Number(value).toFixed(digits);
}

function refresh() {
  const s = JSON.parse(page.state());
  if (s.error) { status(s.error, "error"); return; }
  const d = s.drive;
  const state = $("state");
  state.textContent = d.state;
  // status word 1 (2100H): 1 forward running, 2 reverse running, 3 stopped, 4 fault, 5 off
  state.className = `value state${d.status === 4 ? " fault" : d.status === 1 || d.status === 2 ? " running" : ""}`;
  $("channel").value = ["keypad", "terminals", "communication"][d.run_channel] ?? "";
  $("speed").textContent = fmt(d.speed_rpm, 0);
  $("setspeed").textContent = fmt(d.set_speed_rpm, 0);
  $("current").textContent = fmt(d.current_a, 2);
  $("bus").textContent = fmt(d.bus_v, 1);
  $("fault").textContent = d.fault_code ? `0x${d.fault_code.toString(16).padStart(2, "0").toUpperCase()} ${d.fault_name}` : "none";
  $("time").textContent = fmt(s.clock.t, 2);
  $("serial-baud").textContent = s.baud;
  for (const input of document.querySelectorAll("#conditions-form input")) {
    const value = d.conditions[input.name];
    if (document.activeElement !== input && typeof value === "number") input.value = +value.toFixed(4);
  }
  if (serial) {
    const st = serial.stats;
    $("serial-state").textContent = `serving at ${st.baud} baud ${st.format}: ${st.bytesIn} bytes in (${st.chunks} reads), ${st.replies} replies out`;
  }
  drawPlot();
  refreshFrames();
  refreshAudit();
}

function drawPlot() {
  const canvas = $("plot");
  const ctx = canvas.getContext("2d");
  const w = canvas.width;
  const h = canvas.height;
  ctx.clearRect(0, 0, w, h);
  ctx.strokeStyle = "#d6dbe1";
  ctx.beginPath();
  ctx.moveTo(0, h / 2);
  ctx.lineTo(w, h / 2);
  ctx.stroke();
  if (history.length < 2) return;
  const t0 = history[0].t;
  const t1 = history[history.length - 1].t;
  const span = Math.max(t1 - t0, 1e-6);
  const maxRpm = Math.max(100, ...history.map((p) => Math.abs(p.speed_rpm || 0))) * 1.1;
  const maxA = Math.max(0.5, ...history.map((p) => Math.abs(p.current_a || 0))) * 1.1;
  const line = (key, max, colour) => {
    ctx.strokeStyle = colour;
    ctx.lineWidth = 2;
    ctx.beginPath();
    history.forEach((p, i) => {
      const x = ((p.t - t0) / span) * (w - 2) + 1;
      const y = h / 2 - ((p[key] || 0) / max) * (h / 2 - 4);
      if (i === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
    });
    ctx.stroke();
  };
  line("speed_rpm", maxRpm, "#1f6fd1");
  line("current_a", maxA, "#d9822b");
  ctx.fillStyle = "#5c6773";
  ctx.font = "11px sans-serif";
  ctx.fillText(`${maxRpm.toFixed(0)} rpm / ${maxA.toFixed(2)} A`, 4, 12);
  ctx.fillText(`${t0.toFixed(1)} s`, 4, h - 4);
  ctx.fillText(`${t1.toFixed(1)} s`, w - 40, h - 4);
}

function refreshFrames() {
  const frames = JSON.parse(page.frames(lastSeq, 100));
  if (!frames.length) return;
  const body = $("frames");
  for (const f of frames) {
    lastSeq = f.seq + 1;
    const tr = document.createElement("tr");
    for (const [text, cls] of [[f.seq, ""], [f.t.toFixed(4), ""], [f.dir, ""], [f.hex, "hex"], [f.text + (f.note ? ` (${f.note})` : ""), ""]]) {
      const td = document.createElement("td");
      td.textContent = text;
      if (cls) td.className = cls;
      tr.append(td);
    }
    body.append(tr);
    frameRows.push(tr);
  }
  while (frameRows.length > 200) frameRows.shift().remove();
  body.scrollTop = body.scrollHeight;
}

function refreshAudit() {
  const report = JSON.parse(page.audit_report());
  const list = $("findings");
  list.textContent = "";
  if (report.error) { list.textContent = report.error; return; }
  $("audit-worst").textContent = report.worst ? `(${report.worst})` : "";
  if (!report.findings.length) {
    const li = document.createElement("li");
    li.textContent = report.frames ? `no findings in ${report.frames} frames` : "no frames yet";
    list.append(li);
  }
  for (const f of report.findings) {
    const li = document.createElement("li");
    li.className = f.severity;
    li.textContent = f.line;
    list.append(li);
  }
}

// --- What the user does.

function act(what) {
  try {
    what();
  } catch (err) {
    note(err.message, true);
  }
  if (info.clock === "virtual") sample();
  refresh();
}

function setCondition(name, input) {
  act(() => {
    call("set_conditions", {}, { [name]: Number(input.value) });
    note(`${name} = ${input.value}`);
  });
}

function advance(seconds) {
  const answer = JSON.parse(page.advance(seconds, Math.max(2, Math.round(seconds * 20))));
  if (answer.error) { note(answer.error, true); return; }
  history.push(...answer.samples);
  if (history.length > HISTORY) history.splice(0, history.length - HISTORY);
  refresh();
}

async function sendFrame() {
  const text = $("frame").value;
  const answer = JSON.parse(await page.terminal(text, $("add-crc").checked));
  const box = $("exchanges");
  const div = document.createElement("div");
  div.className = "exchange";
  if (answer.error) {
    div.innerHTML = `<div class="error"></div>`;
    div.firstChild.textContent = answer.error;
  } else {
    for (const x of answer.exchanges) {
      const req = document.createElement("div");
      req.innerHTML = `&rarr; <span class="hex request"></span> <span class="words"></span>`;
      req.children[0].textContent = x.request;
      req.children[1].textContent = x.request_text;
      const rep = document.createElement("div");
      rep.innerHTML = `&larr; <span class="hex reply"></span> <span class="words"></span>`;
      rep.children[0].textContent = x.reply ?? "(none)";
      rep.children[1].textContent = x.reply_text;
      if (x.exception) rep.children[1].classList.add("exc");
      div.append(req, rep);
    }
  }
  box.prepend(div);
  while (box.children.length > 50) box.lastChild.remove();
  if (info.clock === "virtual") sample();
  refresh();
  return answer;
}
c20.sendFrame = sendFrame;

function wire() {
  for (const b of document.querySelectorAll("[data-key]")) {
    b.addEventListener("click", () => act(() => {
      const answer = call("press_key", {}, { key: b.dataset.key });
      note(`${b.textContent}: ${answer.accepted ? "accepted" : "refused by the drive (its run channel is not the keypad)"}`);
    }));
  }
  for (const b of document.querySelectorAll("[data-advance]")) {
    b.addEventListener("click", () => advance(Number(b.dataset.advance)));
  }
  $("speed-form").addEventListener("submit", (e) => {
    e.preventDefault();
    act(() => {
      const answer = call("write_register", { register: "2001H" }, { value: Number($("speed-input").value) });
      note(`2001H = ${answer.raw}`);
    });
  });
  $("fault-form").addEventListener("submit", (e) => {
    e.preventDefault();
    act(() => note(call("fault", {}, { cause: $("cause").value }).note || `${$("cause").value}: brought about`));
  });
  $("clear-fault").addEventListener("click", () => act(() => {
    const answer = call("clear_fault", {}, {});
    note(answer.note || (answer.reset ? "fault reset" : "no fault to reset"));
  }));
  $("channel").addEventListener("change", () => act(() => {
    call("set_run_channel", {}, { channel: $("channel").value });
    note(`run channel: ${$("channel").value}`);
  }));
  $("pick").addEventListener("change", () => { if ($("pick").value) $("frame").value = $("pick").value; });
  $("terminal-form").addEventListener("submit", (e) => { e.preventDefault(); sendFrame(); });
  $("restart").addEventListener("click", () => start({ name: $("profile").value }));
  $("profile").addEventListener("change", () => start({ name: $("profile").value }));
  $("clock").addEventListener("change", () => start({ name: info.profiles.includes(info.source) ? info.source : "" }));
  const drop = $("drop");
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  document.addEventListener("dragover", (e) => e.preventDefault());
  document.addEventListener("drop", async (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    const file = e.dataTransfer.files[0];
    if (file) start({ text: await file.text(), filename: file.name });
  });
  c20.loadProfileText = (text, filename) => start({ text, filename });
  $("serial-open").addEventListener("click", openSerial);
  $("serial-close").addEventListener("click", closeSerial);
}

async function openSerial() {
  if (!("serial" in navigator)) {
    $("serial-state").textContent = "this browser has no Web Serial: use Chrome or Edge (version 89 or later), on a page served over https or from localhost";
    return;
  }
  let port;
  try {
    port = await navigator.serial.requestPort();
  } catch (err) {
    $("serial-state").textContent = `no port chosen (${err.message})`;
    return;
  }
  await useSerial(port);
}

async function useSerial(port) {
  if (serial) await closeSerial();
  const say = (text) => { $("serial-state").textContent = text; };
  try {
    serial = await serveOn(port, page, { format: $("format").value, log: say });
  } catch (err) {
    say(`cannot open the port: ${err.message}`);
    return null;
  }
  $("serial-open").disabled = true;
  $("serial-close").disabled = false;
  serial.done.then(() => { $("serial-open").disabled = false; $("serial-close").disabled = true; });
  return serial;
}
c20.useSerial = useSerial;

async function closeSerial() {
  if (!serial) return;
  const s = serial;
  serial = null;
  await s.close();
}

// Realtime clock aside, the panel is redrawn whenever frames arrive on the serial port.
setInterval(() => { if (page && serial && info.clock === "virtual") refresh(); }, 250);

wire();
c20.ready = boot().catch((err) => {
  status(`cannot start: ${oneLine(err)}`, "error");
  throw err;
});
