// bavo-teleop page: shows the frames the server sends and sends the operator's input.
// The server runs the control loop at 25 Hz; this page only reports which keys / buttons are held,
// the edges (taps) between ticks, the gamepad axes and the WebXR poses.
"use strict";

const MOTION = new Set(["w", "a", "s", "d", "r", "f", "q", "e", "t", "g", "shift"]);
const TAPS = new Set(["1", "2", "3", " ", "l"]);
const COMMANDS = { n: "start", enter: "save", backspace: "discard", z: "rerecord", x: "stop" };

const bavo = (window.bavo = {
  connected: false, status: {}, frames: 0, latencies: [], lastHeader: null, errors: [],
});
// The run's token, from the address bavo-teleop printed; the server refuses the websocket without it.
const TOKEN = new URLSearchParams(location.search).get("token") || "";
const MAX_PAD_BUTTONS = 17; // the standard mapping's buttons: the server accepts pad0..pad16
// what the server accepts for axes and triggers (a driver's stray value would get the whole message refused)
const clamp = (v, lo, hi) => (Number.isFinite(v) ? Math.min(hi, Math.max(lo, v)) : 0);
const held = new Set();
const padHeld = new Set();
let pad = null;
let seq = 0;
const pending = new Map(); // input seq -> performance.now() at the key press (latency)
let ws = null;

function $(id) { return document.getElementById(id); }

function send(obj) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(obj));
}

function sendInput(taps, track) {
  seq += 1;
  if (track && bavo.status.state === "running") pending.set(seq, performance.now());
  // pad is always sent (null too): a gamepad that went away must not leave its last axes held
  send({ type: "input", seq, keys: [...held, ...padHeld], taps, pad });
}

function command(cmd) { send({ type: "cmd", cmd }); }

function keyName(e) { return e.key === " " ? " " : e.key.toLowerCase(); }

window.addEventListener("keydown", (e) => {
  const k = keyName(e);
  if (e.ctrlKey || e.metaKey || e.altKey) return;
  if (k in COMMANDS) {
    e.preventDefault();
    if (!e.repeat) command(COMMANDS[k]);
    return;
  }
  if (MOTION.has(k) || TAPS.has(k)) {
    e.preventDefault();
    if (e.repeat) return;
    if (MOTION.has(k)) held.add(k);
    sendInput(TAPS.has(k) ? [k] : [], true);
  }
});
window.addEventListener("keyup", (e) => {
  const k = keyName(e);
  if (held.delete(k)) sendInput([], false);
});
window.addEventListener("blur", () => { if (held.size) { held.clear(); sendInput([], false); } });

for (const [id, cmd] of [["b-start", "start"], ["b-stop", "stop"], ["b-save", "save"], ["b-discard", "discard"],
                         ["b-rerecord", "rerecord"]]) {
  $(id).addEventListener("click", (e) => { e.target.blur(); command(cmd); });
}

// ---------------------------------------------------------------- gamepad (standard mapping)
function pollGamepad() {
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  const gp = pads && [...pads].find((p) => p);
  if (!gp) { if (pad !== null) { pad = null; padHeld.clear(); sendInput([], false); } return; }
  const axes = gp.axes.slice(0, 4).map((a) => Math.round(clamp(a, -1, 1) * 100) / 100);
  const taps = [];
  const now = new Set();
  gp.buttons.forEach((b, i) => { if (b.pressed && i < MAX_PAD_BUTTONS) now.add("pad" + i); });
  for (const b of now) if (!padHeld.has(b)) taps.push(b);
  const changed = taps.length || now.size !== padHeld.size || pad === null || axes.some((a, i) => a !== pad[i]);
  padHeld.clear(); now.forEach((b) => padHeld.add(b));
  pad = axes;
  if (changed) sendInput(taps, taps.length > 0 || axes.some((a) => Math.abs(a) > 0.15));
}

// ---------------------------------------------------------------- WebXR
let xrSession = null;
let xrSpace = null;
let xrLastSend = 0;
function poseArray(pose) {
  const p = pose.transform.position, o = pose.transform.orientation;
  return [p.x, p.y, p.z, o.x, o.y, o.z, o.w].map((v) => Math.round(v * 1e5) / 1e5);
}
// In the headset: the active-camera view on a head-locked screen (the same image for both eyes).
let xrGL = null, xrTex = null;
function xrSetupGL(gl) {
  const shader = (type, src) => { const sh = gl.createShader(type); gl.shaderSource(sh, src); gl.compileShader(sh); return sh; };
  const prog = gl.createProgram();
  gl.attachShader(prog, shader(gl.VERTEX_SHADER,
    "attribute vec2 p; varying vec2 uv; void main() { uv = vec2(p.x + 1.0, 1.0 - p.y) * 0.5; gl_Position = vec4(p * 0.8, 0.0, 1.0); }"));
  gl.attachShader(prog, shader(gl.FRAGMENT_SHADER,
    "precision mediump float; varying vec2 uv; uniform sampler2D t; void main() { gl_FragColor = texture2D(t, uv); }"));
  gl.linkProgram(prog);
  gl.useProgram(prog);
  gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer());
  gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, -1, 1, 1, -1, 1, 1]), gl.STATIC_DRAW);
  const loc = gl.getAttribLocation(prog, "p");
  gl.enableVertexAttribArray(loc);
  gl.vertexAttribPointer(loc, 2, gl.FLOAT, false, 0, 0);
  xrTex = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, xrTex);
  for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE],
                        [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]]) gl.texParameteri(gl.TEXTURE_2D, k, v);
  xrGL = gl;
}
function xrDraw(viewer) {
  const layer = xrSession.renderState.baseLayer;
  if (!xrGL || !layer) return;
  const gl = xrGL;
  gl.bindFramebuffer(gl.FRAMEBUFFER, layer.framebuffer);
  gl.clearColor(0.12, 0.12, 0.13, 1);
  gl.clear(gl.COLOR_BUFFER_BIT);
  gl.bindTexture(gl.TEXTURE_2D, xrTex);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, $("active"));
  for (const view of viewer.views) {
    const vp = layer.getViewport(view);
    gl.viewport(vp.x, vp.y, vp.width, vp.height);
    gl.drawArrays(gl.TRIANGLES, 0, 6);
  }
  bavo.xrFramesDrawn = (bavo.xrFramesDrawn || 0) + 1;
}
function onXRFrame(t, frame) {
  xrSession.requestAnimationFrame(onXRFrame);
  const viewer = frame.getViewerPose(xrSpace);
  if (viewer) xrDraw(viewer);
  if (!viewer || t - xrLastSend < 20) return;
  xrLastSend = t;
  const xr = { head: poseArray(viewer) };
  for (const src of xrSession.inputSources) {
    if (!src.gripSpace || (src.handedness !== "left" && src.handedness !== "right")) continue;
    const pose = frame.getPose(src.gripSpace, xrSpace);
    if (pose) xr[src.handedness] = poseArray(pose);
    if (src.gamepad && src.gamepad.buttons.length) xr[src.handedness + "_trigger"] = clamp(src.gamepad.buttons[0].value, 0, 1);
  }
  seq += 1;
  send({ type: "input", seq, keys: [], taps: [], xr });
}
async function setupXR() {
  if (!navigator.xr) { $("xrinfo").textContent = "WebXR: not offered by this browser"; return; }
  let ok = false;
  try { ok = await navigator.xr.isSessionSupported("immersive-vr"); } catch (e) { ok = false; }
  $("xrinfo").textContent = ok ? "WebXR: immersive-vr available" : "WebXR: no immersive-vr device";
  if (!ok) return;
  $("b-xr").style.display = "";
  $("b-xr").addEventListener("click", async () => {
    if (xrSession) { xrSession.end(); return; }
    xrSession = await navigator.xr.requestSession("immersive-vr", { optionalFeatures: ["local-floor"] });
    const gl = document.createElement("canvas").getContext("webgl", { xrCompatible: true });
    if (gl) xrSetupGL(gl);
    bavo.xrWebGL = Boolean(gl);
    xrSession.updateRenderState({ baseLayer: new XRWebGLLayer(xrSession, gl) });
    try { xrSpace = await xrSession.requestReferenceSpace("local-floor"); }
    catch (e) { xrSpace = await xrSession.requestReferenceSpace("local"); }
    xrSession.addEventListener("end", () => {
      xrSession = null; seq += 1; send({ type: "input", seq, keys: [], taps: [], xr: null });
      $("b-xr").textContent = "Enter VR";
    });
    $("b-xr").textContent = "Exit VR";
    xrSession.requestAnimationFrame(onXRFrame);
  });
}

// ---------------------------------------------------------------- frames and status
const activeCtx = $("active").getContext("2d");
const thirdCtx = $("third").getContext("2d");
let latest = null;
let drawing = false;

function showStatus(s) {
  bavo.status = Object.assign({}, bavo.status, s);
  const st = bavo.status;
  $("state").textContent = st.state || "";
  $("msg").textContent = st.message || "";
  $("task").textContent = st.task || "?";
  $("condition").textContent = st.condition || "?";
  if (st.episodes !== undefined) $("episodes").textContent = st.episodes;
  if (st.help) $("help").textContent = st.help;
}

function showHeader(h) {
  showStatus(h);
  $("tick").textContent = `${h.tick} / ${h.max_steps}`;
  $("seed").textContent = h.seed;
  for (let i = 1; i <= 5; i++) $("m" + i).classList.toggle("on", h.progress >= i);
  const occ = h.occlusion;
  if (occ) {
    $("occ").textContent = `event ${occ.event + 1} of ${occ.events}: target ${occ.target}` +
      (h.recovering ? " (recovering the view)" : "");
    const v = occ.visibility;
    $("occ").classList.toggle("on", v !== null && v < 0.5);
    $("vis").textContent = v === null ? "V = -" : `V = ${v.toFixed(2)}`;
    $("visfill").style.width = v === null ? "0" : `${Math.round(v * 100)}%`;
  } else {
    $("occ").textContent = "none (clean)";
  }
  if (h.arm) for (const a of ["left", "right", "camera"]) $("arm-" + a).classList.toggle("on", h.arm === a);
  if (h.look_at !== undefined) {
    $("lookat").textContent = h.look_at ? "look-at on" : "look-at off";
    $("lookat").classList.toggle("on", h.look_at);
  }
  if (h.grippers) $("grip").textContent = `L ${h.grippers.left.toFixed(1)}  R ${h.grippers.right.toFixed(1)}`;
  if (h.control_hz) $("hz").textContent = `${h.control_hz} Hz`;
}

async function drawLatest() {
  if (drawing || latest === null) return;
  drawing = true;
  const { header, a, b } = latest;
  latest = null;
  try {
    const [ia, ib] = await Promise.all([createImageBitmap(a), createImageBitmap(b)]);
    activeCtx.drawImage(ia, 0, 0, 640, 480);
    thirdCtx.drawImage(ib, 0, 0, 320, 240);
    ia.close(); ib.close();
    showHeader(header);
    bavo.lastHeader = header;
    bavo.frames += 1;
    const ack = header.ack || 0;
    requestAnimationFrame(() => {
      const now = performance.now();
      for (const [s, t] of pending) {
        if (s <= ack) { bavo.latencies.push(now - t); pending.delete(s); }
      }
      const l = bavo.latencies.slice(-50).sort((x, y) => x - y);
      if (l.length) $("lat").textContent = `${l[Math.floor(l.length / 2)].toFixed(0)} ms (median of ${l.length})`;
    });
  } finally {
    drawing = false;
    if (latest !== null) drawLatest();
  }
}

function onMessage(ev) {
  if (typeof ev.data === "string") {
    const m = JSON.parse(ev.data);
    if (m.type === "error") { // a message of ours the server refused, or a failure in the simulation
      bavo.errors.push(m.error);
      console.warn("bavo-teleop:", m.error);
      $("msg").textContent = "error: " + m.error;
      return;
    }
    showStatus(m);
    if (bavo.status.state !== "running") pending.clear();
    return;
  }
  const buf = ev.data;
  const dv = new DataView(buf);
  const hl = dv.getUint32(0, true), al = dv.getUint32(4, true), bl = dv.getUint32(8, true);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 12, hl)));
  const a = new Blob([new Uint8Array(buf, 12 + hl, al)], { type: "image/jpeg" });
  const b = new Blob([new Uint8Array(buf, 12 + hl + al, bl)], { type: "image/jpeg" });
  latest = { header, a, b };
  drawLatest();
}

function connect() {
  ws = new WebSocket(`ws://${location.host}/ws?token=${encodeURIComponent(TOKEN)}`);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { bavo.connected = true; };
  ws.onclose = () => {
    bavo.connected = false;
    showStatus({ state: "disconnected", message: bavo.frames === 0 && !TOKEN
      ? "refused: open the address bavo-teleop printed (it ends in ?token=...)"
      : "disconnected (server stopped, or refused this page; saved episodes are kept): reload to reconnect" });
  };
  ws.onmessage = onMessage;
}

function loop() {
  pollGamepad();
  requestAnimationFrame(loop);
}

connect();
setupXR();
requestAnimationFrame(loop);
