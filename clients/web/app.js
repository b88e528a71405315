// puppetry web renderer: a thin client of the stream protocol (docs/protocol.md).
// Viewers draw the stage; performers also send their pointers as contacts.

const params = new URLSearchParams(location.search);
const role = params.get('role') === 'performer' ? 'performer' : 'viewer';
const token = params.get('token') ?? '';
// `?calibrate=0.1` shows the four marks `puppetry calibrate` expects, that
// fraction of the stage in from its edges, numbered in the order to touch.
const calibrateInset = params.has('calibrate') ? Number(params.get('calibrate') || 0.1) : null;

const stageEl = document.getElementById('stage');
const glCanvas = document.getElementById('gl');
const overlay = document.getElementById('overlay');
const ctx2d = overlay.getContext('2d');
const statusEl = document.getElementById('status');
const pinButton = document.getElementById('pin-tool');
const paintControls = document.getElementById('paint-controls');
const paintButton = document.getElementById('paint-tool');
const paintRadius = document.getElementById('paint-radius');
const paintStrength = document.getElementById('paint-strength');
const saveButton = document.getElementById('save-weights');
const poseControls = document.getElementById('pose-controls');
const poseFrom = document.getElementById('pose-from');
const poseTo = document.getElementById('pose-to');
const poseT = document.getElementById('pose-t');

// Test and debugging surface (see tests/web/drag.mjs).
const api = window.puppetry = {
  connected: false,
  framesReceived: 0,
  weightsReceived: 0,
  lastSequence: {},          // puppet id -> newest sequence number received
  rigFrames: 0,              // rig frames (grid handles, joints) received
  errors: [],                // server "error" messages and client-side failures
  stage: null,               // the last stage message
  ready: false,              // stage received and every texture settled
  stageToClient,
  snapshot,
};

let stage = null;            // {width, height} in stage units
let cursors = [];            // mouse cursors on the stage, from "cursors" messages
let myOwner = '';            // "client:N", to tell our own handles apart
let puppets = [];            // GL state per puppet, in stage order (drawn bottom to top)
let needsDraw = true;
let needsOverlay = true;

// ---------------------------------------------------------------- status

function setStatus(text, isError = false) {
  statusEl.textContent = text;
  statusEl.classList.toggle('error', isError);
}

function reportError(message) {
  api.errors.push(message);
  if (api.errors.length > 50) api.errors.shift();
  setStatus(`error: ${message}`, true);
  console.warn('puppetry:', message);
}

// ---------------------------------------------------------------- WebGL

const VERTEX_SHADER = `
attribute vec2 a_pos;
attribute vec2 a_uv;
uniform vec2 u_stage;
varying vec2 v_uv;
void main() {
  v_uv = a_uv;
  // Stage and clip space are both y-up, so no flip here.
  gl_Position = vec4(a_pos / u_stage * 2.0 - 1.0, 0.0, 1.0);
}`;

const FRAGMENT_SHADER = `
precision mediump float;
uniform sampler2D u_tex;
varying vec2 v_uv;
void main() { gl_FragColor = texture2D(u_tex, v_uv); }`;

let gl, program, loc, placeholder;
const textures = new Map(); // url -> WebGLTexture, shared by puppets with one picture

function initGL() {
  gl = glCanvas.getContext('webgl', { alpha: false, antialias: true });
  if (!gl) throw new Error('WebGL is not available');
  const shader = (type, src) => {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  };
  program = gl.createProgram();
  gl.attachShader(program, shader(gl.VERTEX_SHADER, VERTEX_SHADER));
  gl.attachShader(program, shader(gl.FRAGMENT_SHADER, FRAGMENT_SHADER));
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  loc = {
    pos: gl.getAttribLocation(program, 'a_pos'),
    uv: gl.getAttribLocation(program, 'a_uv'),
    stage: gl.getUniformLocation(program, 'u_stage'),
  };
  gl.enableVertexAttribArray(loc.pos);
  gl.enableVertexAttribArray(loc.uv);
  // Pictures have soft alpha edges: upload premultiplied and blend accordingly.
  gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, true);
  // uv has v down from the top of the picture, and WebGL stores the first image
  // row at t = 0: so no flip. (Flipping would need v' = 1 - v.)
  gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
  // Shown until a picture has loaded, so the mesh is visible at once.
  placeholder = makeTexture(new Uint8Array([200, 200, 200, 255]));
  textures.clear();
}

function makeTexture(pixel) {
  const tex = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, tex);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, 1, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE, pixel);
  // WebGL1 cannot mipmap or repeat non-power-of-two pictures.
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  return tex;
}

function loadTexture(url) {
  if (textures.has(url)) return Promise.resolve();
  const tex = makeTexture(new Uint8Array([0, 0, 0, 0]));
  textures.set(url, tex);
  const img = new Image();
  img.src = url;
  return img.decode().then(
    () => {
      if (textures.get(url) !== tex) return; // context was rebuilt meanwhile
      gl.bindTexture(gl.TEXTURE_2D, tex);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, img);
      needsDraw = true;
    },
    () => reportError(`cannot load texture ${url}`),
  );
}

function buildPuppets(msg) {
  for (const p of puppets) {
    gl.deleteBuffer(p.posBuf);
    gl.deleteBuffer(p.uvBuf);
    gl.deleteBuffer(p.idxBuf);
  }
  const old = new Map(puppets.map((p) => [p.id, p]));
  puppets = msg.puppets.map((src) => {
    const n = src.rest.length / 2;
    // Keep the newest positions across a context loss; a new stage starts at rest.
    const kept = old.get(src.id)?.src === src ? old.get(src.id) : null;
    const positions = kept ? kept.positions : new Float32Array(src.rest);
    const big = n > 65535;
    if (big && !gl.getExtension('OES_element_index_uint')) {
      reportError(`puppet ${src.id} has ${n} vertices; this GPU draws at most 65535`);
    }
    const posBuf = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, posBuf);
    gl.bufferData(gl.ARRAY_BUFFER, positions, gl.DYNAMIC_DRAW);
    const uvBuf = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, uvBuf);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(src.uv), gl.STATIC_DRAW);
    const idxBuf = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, idxBuf);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, big ? new Uint32Array(src.triangles) : new Uint16Array(src.triangles), gl.STATIC_DRAW);
    return {
      id: src.id, src, n, positions, dirty: false,
      posBuf, uvBuf, idxBuf,
      idxType: big ? gl.UNSIGNED_INT : gl.UNSIGNED_SHORT,
      count: src.triangles.length,
      texture: src.texture,
      handles: kept?.handles ?? src.handles ?? [],
      // The rig as the stage describes it, and its newest points (deformed
      // grid handles or posed joints) from rig frames.
      rig: src.rig ?? { kind: 'free' },
      rigPoints: kept?.rigPoints ?? (src.rig?.rest ? new Float32Array(src.rig.rest.flat()) : null),
      // Per-triangle stiffness, shown while the paint tool is on.
      weights: kept?.weights ?? src.weights ?? null,
    };
  });
  return Promise.all(msg.puppets.map((p) => loadTexture(p.texture)));
}

function draw() {
  gl.viewport(0, 0, glCanvas.width, glCanvas.height);
  gl.clearColor(0.96, 0.95, 0.92, 1);
  gl.clear(gl.COLOR_BUFFER_BIT);
  if (!stage) return;
  gl.useProgram(program);
  gl.uniform2f(loc.stage, stage.width, stage.height);
  for (const p of puppets) {
    gl.bindBuffer(gl.ARRAY_BUFFER, p.posBuf);
    if (p.dirty) {
      // Only the newest frame is uploaded, straight from the message's buffer.
      gl.bufferSubData(gl.ARRAY_BUFFER, 0, p.positions);
      p.dirty = false;
    }
    gl.vertexAttribPointer(loc.pos, 2, gl.FLOAT, false, 0, 0);
    gl.bindBuffer(gl.ARRAY_BUFFER, p.uvBuf);
    gl.vertexAttribPointer(loc.uv, 2, gl.FLOAT, false, 0, 0);
    gl.bindTexture(gl.TEXTURE_2D, textures.get(p.texture) ?? placeholder);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, p.idxBuf);
    gl.drawElements(gl.TRIANGLES, p.count, p.idxType, 0);
  }
}

// Draws now and reads the result back in the same task, before the browser
// presents (and may clear) the drawing buffer. For tests: RGBA bytes, bottom row first.
function snapshot() {
  draw();
  const px = new Uint8Array(glCanvas.width * glCanvas.height * 4);
  gl.readPixels(0, 0, glCanvas.width, glCanvas.height, gl.RGBA, gl.UNSIGNED_BYTE, px);
  return px;
}

glCanvas.addEventListener('webglcontextlost', (e) => {
  e.preventDefault(); // tells the browser we will rebuild, so it restores the context
  reportError('graphics context lost');
});
glCanvas.addEventListener('webglcontextrestored', () => {
  initGL();
  if (api.stage) buildPuppets(api.stage);
  needsDraw = true;
  setStatus('graphics context restored');
});

// ---------------------------------------------------------------- layout

function layout() {
  const w = stage?.width ?? 16;
  const h = stage?.height ?? 9;
  const scale = Math.min(innerWidth / w, innerHeight / h);
  const cssW = w * scale;
  const cssH = h * scale;
  Object.assign(stageEl.style, {
    width: `${cssW}px`, height: `${cssH}px`,
    left: `${(innerWidth - cssW) / 2}px`, top: `${(innerHeight - cssH) / 2}px`,
  });
  const dpr = devicePixelRatio || 1;
  for (const c of [glCanvas, overlay]) {
    c.width = Math.max(1, Math.round(cssW * dpr));
    c.height = Math.max(1, Math.round(cssH * dpr));
  }
  needsDraw = needsOverlay = true;
}

addEventListener('resize', layout);

function stageToClient(x, y) {
  const r = stageEl.getBoundingClientRect();
  if (!stage) return [r.left, r.top];
  return [r.left + (x / stage.width) * r.width, r.top + (1 - y / stage.height) * r.height];
}

function clientToStage(cx, cy) {
  const r = stageEl.getBoundingClientRect();
  return [((cx - r.left) / r.width) * stage.width, (1 - (cy - r.top) / r.height) * stage.height];
}

// ---------------------------------------------------------------- handles overlay

// A stable colour per owner, so everyone sees whose hand is whose.
function ownerColour(owner, alpha = 1) {
  if (owner === 'config') return `rgb(158 158 158 / ${alpha})`;
  let h = 0;
  for (const ch of owner) h = (h * 31 + ch.charCodeAt(0)) >>> 0;
  return `hsl(${h % 360} 85% 50% / ${alpha})`;
}

function drawOverlay() {
  const dpr = overlay.width / stageEl.clientWidth || 1;
  const r = stageEl.getBoundingClientRect();
  ctx2d.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx2d.clearRect(0, 0, overlay.width, overlay.height);
  const dot = (x, y, radius, fill, ring) => {
    const [cx, cy] = stageToClient(x, y);
    ctx2d.beginPath();
    ctx2d.arc(cx - r.left, cy - r.top, radius, 0, 2 * Math.PI);
    if (fill) { ctx2d.fillStyle = fill; ctx2d.fill(); }
    ctx2d.lineWidth = 2;
    ctx2d.strokeStyle = ring;
    ctx2d.stroke();
  };
  // Rigs under the handles: the deformed grid (lines and handle dots) and
  // the skeleton (bones and joints).
  const line = (ax, ay, bx, by) => {
    const [x0, y0] = stageToClient(ax, ay);
    const [x1, y1] = stageToClient(bx, by);
    ctx2d.moveTo(x0 - r.left, y0 - r.top);
    ctx2d.lineTo(x1 - r.left, y1 - r.top);
  };
  for (const p of puppets) {
    const q = p.rigPoints;
    if (!q) continue;
    const at = (i) => [q[2 * i], q[2 * i + 1]];
    ctx2d.beginPath();
    if (p.rig.kind === 'grid') {
      const { columns: m, rows: n } = p.rig;
      for (let row = 0; row < n; row++) {
        for (let col = 0; col < m; col++) {
          const i = row * m + col;
          if (col + 1 < m) line(...at(i), ...at(i + 1));
          if (row + 1 < n) line(...at(i), ...at(i + m));
        }
      }
      ctx2d.lineWidth = 1;
      ctx2d.strokeStyle = 'rgb(41 98 255 / 0.6)';
    } else if (p.rig.kind === 'skeleton') {
      for (const [a, b] of p.rig.bones) line(...at(a), ...at(b));
      ctx2d.lineWidth = 4;
      ctx2d.strokeStyle = 'rgb(255 111 0 / 0.75)';
    }
    ctx2d.stroke();
    const count = q.length / 2;
    for (let i = 0; i < count; i++) {
      const [x, y] = at(i);
      if (p.rig.kind === 'grid') dot(x, y, 3, 'rgb(41 98 255 / 0.8)', 'rgb(255 255 255 / 0.8)');
      else dot(x, y, 5, 'rgb(255 111 0 / 0.9)', '#000');
    }
  }
  if (paintTool) {
    // Painted stiffness: stiffer blue, softer red, stronger the further
    // from the default weight 1 (on a log scale).
    for (const p of puppets) {
      if (!p.weights) continue;
      const v = p.positions;
      const t = p.src.triangles;
      for (let k = 0; k < p.weights.length; k++) {
        const w = p.weights[k];
        if (w === 1) continue;
        const strength = Math.min(1, Math.abs(Math.log10(w)) / 3);
        ctx2d.fillStyle = w > 1 ? `rgb(41 98 255 / ${0.15 + 0.5 * strength})` : `rgb(213 0 0 / ${0.15 + 0.5 * strength})`;
        ctx2d.beginPath();
        for (let c = 0; c < 3; c++) {
          const i = t[3 * k + c];
          const [x, y] = stageToClient(v[2 * i], v[2 * i + 1]);
          if (c === 0) ctx2d.moveTo(x - r.left, y - r.top); else ctx2d.lineTo(x - r.left, y - r.top);
        }
        ctx2d.fill();
      }
    }
  }
  if (paintTool && brush) {
    const [cx, cy] = stageToClient(brush.x, brush.y);
    const [ex] = stageToClient(brush.x + Number(paintRadius.value), brush.y);
    ctx2d.beginPath();
    ctx2d.arc(cx - r.left, cy - r.top, Math.abs(ex - cx), 0, 2 * Math.PI);
    ctx2d.lineWidth = 1.5;
    ctx2d.strokeStyle = Number(paintStrength.value) >= 1 ? '#2962ff' : '#d50000';
    ctx2d.stroke();
  }
  for (const p of puppets) {
    for (const h of p.handles) {
      // Our own contacts are drawn where the pointer is now (below): "handles"
      // messages come only when the set changes, so their `at` goes stale.
      if (h.kind === 'contact' && h.owner === myOwner) continue;
      if (h.kind === 'pin') dot(h.at[0], h.at[1], 6, ownerColour(h.owner), '#000');
      else dot(h.at[0], h.at[1], 10, ownerColour(h.owner, 0.6), 'rgb(0 0 0 / 0.6)');
    }
  }
  for (const { x, y } of active.values()) dot(x, y, 10, ownerColour(myOwner, 0.6), 'rgb(0 0 0 / 0.6)');
  if (calibrateInset !== null && api.stage) {
    const { width: w, height: h } = api.stage.stage;
    const lo = calibrateInset, hi = 1 - calibrateInset;
    const marks = [[lo * w, hi * h], [hi * w, hi * h], [hi * w, lo * h], [lo * w, lo * h]];
    ctx2d.font = 'bold 20px sans-serif';
    marks.forEach(([x, y], i) => {
      const [cx, cy] = stageToClient(x, y);
      const px = cx - r.left, py = cy - r.top;
      ctx2d.lineWidth = 2;
      ctx2d.strokeStyle = '#e00';
      ctx2d.beginPath();
      ctx2d.moveTo(px - 20, py); ctx2d.lineTo(px + 20, py);
      ctx2d.moveTo(px, py - 20); ctx2d.lineTo(px, py + 20);
      ctx2d.stroke();
      ctx2d.fillStyle = '#e00';
      ctx2d.fillText(String(i + 1), px + 8, py - 8);
    });
  }
  // Mice on the stage: a cross at the cursor and the pair of points it
  // holds (filled while its button is down).
  for (const c of cursors) {
    const [cx, cy] = stageToClient(c.at[0], c.at[1]);
    const colour = ownerColour(c.source);
    ctx2d.lineWidth = 2;
    ctx2d.strokeStyle = colour;
    ctx2d.beginPath();
    ctx2d.moveTo(cx - r.left - 8, cy - r.top); ctx2d.lineTo(cx - r.left + 8, cy - r.top);
    ctx2d.moveTo(cx - r.left, cy - r.top - 8); ctx2d.lineTo(cx - r.left, cy - r.top + 8);
    ctx2d.stroke();
    if (c.spacing > 0) {
      const dx = Math.cos(c.angle) * c.spacing / 2, dy = Math.sin(c.angle) * c.spacing / 2;
      for (const s of [-1, 1]) {
        dot(c.at[0] + s * dx, c.at[1] + s * dy, 6, c.holding ? ownerColour(c.source, 0.7) : null, colour);
      }
    }
  }
}

// ---------------------------------------------------------------- performer input

const active = new Map(); // pointerId -> latest stage point, for contacts that went "down"
let queue = [];           // contact events not yet sent, in order
let pinTool = false;
let paintTool = false;
let brush = null;          // {x, y, down} where the paint brush is (stage coordinates)
const painted = new Set(); // puppet ids painted since the last save

function pinOrUnpin(x, y, cx, cy) {
  // A pin within reach of the click is removed; otherwise a new one is made.
  let best = null;
  let bestDist = 12; // CSS pixels
  for (const p of puppets) {
    for (const h of p.handles) {
      if (h.kind !== 'pin') continue;
      const [hx, hy] = stageToClient(h.at[0], h.at[1]);
      const d = Math.hypot(hx - cx, hy - cy);
      if (d < bestDist) { best = { puppet: p.id, handle: h.id }; bestDist = d; }
    }
  }
  send(best ? { type: 'unpin', ...best } : { type: 'pin', x, y });
}

stageEl.addEventListener('pointerdown', (e) => {
  if (role !== 'performer' || !api.connected) return;
  const [x, y] = clientToStage(e.clientX, e.clientY);
  if (paintTool) {
    stageEl.setPointerCapture(e.pointerId);
    brush = { x, y, down: true, dirty: true };
    needsOverlay = true;
    return;
  }
  if (e.shiftKey || pinTool) {
    pinOrUnpin(x, y, e.clientX, e.clientY);
    return;
  }
  if (e.pointerType === 'mouse' && e.button !== 0) return;
  // Capture: moves and the lift still reach us when the finger leaves the stage.
  stageEl.setPointerCapture(e.pointerId);
  active.set(e.pointerId, { x, y });
  queue.push({ id: e.pointerId, phase: 'down', x, y });
});

stageEl.addEventListener('pointermove', (e) => {
  if (paintTool) {
    const [x, y] = clientToStage(e.clientX, e.clientY);
    brush = { x, y, down: brush?.down ?? false, dirty: true };
    needsOverlay = true;
    return;
  }
  const c = active.get(e.pointerId);
  if (!c) return; // hovering mouse, or a contact from before a reconnect
  [c.x, c.y] = clientToStage(e.clientX, e.clientY);
  queue.push({ id: e.pointerId, phase: 'move', x: c.x, y: c.y });
});

function lift(e) {
  if (brush) brush.down = false;
  if (!active.delete(e.pointerId)) return;
  queue.push({ id: e.pointerId, phase: 'up' });
  needsOverlay = true;
}
stageEl.addEventListener('pointerup', lift);
stageEl.addEventListener('pointercancel', lift);

// One "contacts" message per animation frame. Each contact appears at most
// once in it: successive moves collapse into the newest, and anything after a
// contact's first event otherwise (a move right after "down", an "up") waits
// for the next frame, so the server never has to order two events of one id.
function flushContacts() {
  if (queue.length === 0) return;
  const batch = new Map();
  const rest = [];
  const deferred = new Set();
  for (const ev of queue) {
    const prev = batch.get(ev.id);
    if (!deferred.has(ev.id) && (!prev || (prev.phase === 'move' && ev.phase === 'move'))) {
      batch.set(ev.id, ev);
    } else {
      deferred.add(ev.id);
      rest.push(ev);
    }
  }
  queue = rest;
  send({ type: 'contacts', contacts: [...batch.values()] });
  needsOverlay = true;
}

// One dab per animation frame while the brush is down, on every puppet
// whose current outline box it touches (the server paints only triangles
// under it).
function flushPaint() {
  if (!paintTool || !brush?.down) return;
  const radius = Number(paintRadius.value);
  const strength = Number(paintStrength.value);
  if (!(radius > 0 && strength > 0)) return reportError('paint radius and strength must be positive');
  for (const p of puppets) {
    const v = p.positions;
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    for (let i = 0; i < v.length; i += 2) {
      x0 = Math.min(x0, v[i]); x1 = Math.max(x1, v[i]);
      y0 = Math.min(y0, v[i + 1]); y1 = Math.max(y1, v[i + 1]);
    }
    if (brush.x + radius < x0 || brush.x - radius > x1 || brush.y + radius < y0 || brush.y - radius > y1) continue;
    send({ type: 'paint', puppet: p.id, x: brush.x, y: brush.y, radius, strength });
    painted.add(p.id);
  }
}

function setupPoses() {
  // Key poses of the first skeleton puppet that has some.
  const p = puppets.find((q) => q.rig.kind === 'skeleton' && q.rig.poses?.length);
  poseControls.hidden = role !== 'performer' || !p;
  if (!p) return;
  for (const select of [poseFrom, poseTo]) {
    select.replaceChildren(...p.rig.poses.map((name) => new Option(name, name)));
  }
  if (p.rig.poses.length > 1) poseTo.selectedIndex = 1;
  poseControls.dataset.puppet = String(p.id);
}

function sendPose() {
  send({ type: 'pose', puppet: Number(poseControls.dataset.puppet), from: poseFrom.value, to: poseTo.value, t: Number(poseT.value) });
}

if (role === 'performer') {
  pinButton.hidden = false;
  paintControls.hidden = false;
  pinButton.addEventListener('click', () => {
    pinTool = !pinTool;
    pinButton.setAttribute('aria-pressed', String(pinTool));
  });
  paintButton.addEventListener('click', () => {
    paintTool = !paintTool;
    paintButton.setAttribute('aria-pressed', String(paintTool));
    if (!paintTool) brush = null;
    needsOverlay = true;
  });
  saveButton.addEventListener('click', () => {
    const ids = painted.size ? [...painted] : puppets.map((p) => p.id);
    for (const puppet of ids) send({ type: 'save_weights', puppet });
    painted.clear();
  });
  poseT.addEventListener('input', sendPose);
  poseFrom.addEventListener('change', sendPose);
  poseTo.addEventListener('change', sendPose);
}

// ---------------------------------------------------------------- connection

let ws = null;
let backoff = 500; // ms, doubled per failed attempt up to 10 s
let lastError = '';

function send(msg) {
  if (ws?.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg));
}

function connect() {
  const url = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`;
  setStatus(`connecting to ${url}…`);
  ws = new WebSocket(url);
  ws.binaryType = 'arraybuffer'; // frames are read in place as Float32Array views
  ws.onopen = () => send(role === 'performer' ? { type: 'hello', role, token } : { type: 'hello', role });
  ws.onmessage = (e) => (typeof e.data === 'string' ? onText(e.data) : onFrame(e.data));
  ws.onclose = () => {
    ws = null;
    api.connected = false;
    active.clear(); // the server forgets our contacts with the connection
    queue = [];
    const delay = backoff * (0.75 + Math.random() / 2); // jitter: clients don't return in lockstep
    backoff = Math.min(backoff * 2, 10000);
    setStatus(`disconnected${lastError ? ` (${lastError})` : ''}; retrying in ${(delay / 1000).toFixed(1)} s`, !!lastError);
    setTimeout(connect, delay);
  };
}

function onText(text) {
  let msg;
  try {
    msg = JSON.parse(text);
  } catch {
    reportError('unreadable message from server');
    return;
  }
  switch (msg.type) {
    case 'stage': return onStage(msg);
    case 'handles': {
      const p = puppets.find((q) => q.id === msg.puppet);
      if (p) { p.handles = msg.handles; needsOverlay = true; }
      return;
    }
    case 'cursors':
      cursors = msg.cursors;
      needsOverlay = true;
      return;
    case 'weights': {
      const p = puppets.find((q) => q.id === msg.puppet);
      if (p) { p.weights = msg.weights; needsOverlay = true; }
      api.weightsReceived++;
      return;
    }
    case 'weights_saved':
      setStatus(`painted weights of puppet ${msg.puppet} saved to ${msg.file}`);
      return;
    case 'grid':
      api.lastGrid = msg;
      return;
    case 'error':
      lastError = msg.message;
      return reportError(msg.message);
    default:
      return; // unknown kinds are for newer clients
  }
}

function onStage(msg) {
  api.stage = msg;
  api.ready = false;
  api.lastSequence = {}; // a restarted daemon counts from the start again
  stage = msg.stage;
  myOwner = `client:${msg.client}`;
  backoff = 500;
  lastError = '';
  layout();
  buildPuppets(msg).then(() => { api.ready = true; });
  setupPoses();
  api.connected = true;
  setStatus(`connected as ${msg.role} (client ${msg.client}) · ${msg.puppets.length} puppet(s)`);
}

function onFrame(buf) {
  api.framesReceived++;
  if (buf.byteLength < 32) return reportError('short frame');
  const v = new DataView(buf);
  const kind = v.getUint32(0, true);
  if (kind === 2) return onRigFrame(v, buf);
  if (kind !== 1) return; // a newer kind
  const id = v.getUint32(4, true);
  const seq = Number(v.getBigUint64(8, true));
  const n = v.getUint32(24, true);
  const p = puppets.find((q) => q.id === id);
  if (!p) return reportError(`frame for unknown puppet ${id}`);
  if (n !== p.n || buf.byteLength < 32 + 8 * n) return reportError(`bad frame for puppet ${id}`);
  if (seq <= (api.lastSequence[id] ?? -1)) return; // older than what we have
  api.lastSequence[id] = seq;
  p.positions = new Float32Array(buf, 32, 2 * n);
  p.dirty = true;
  needsDraw = true;
  if (paintTool) needsOverlay = true; // the stiffness tint follows the mesh
}

// A rig frame: the puppet's deformed grid handles or posed joints.
function onRigFrame(v, buf) {
  api.rigFrames++;
  const id = v.getUint32(4, true);
  const n = v.getUint32(24, true);
  const p = puppets.find((q) => q.id === id);
  if (!p) return reportError(`rig frame for unknown puppet ${id}`);
  if (buf.byteLength < 32 + 8 * n) return reportError(`bad rig frame for puppet ${id}`);
  p.rigPoints = new Float32Array(buf, 32, 2 * n);
  needsOverlay = true;
}

// ---------------------------------------------------------------- main loop

function tick() {
  requestAnimationFrame(tick);
  flushContacts();
  flushPaint();
  if (needsDraw) { draw(); needsDraw = false; }
  if (needsOverlay) { drawOverlay(); needsOverlay = false; }
}

try {
  initGL();
  layout();
  connect();
  requestAnimationFrame(tick);
} catch (err) {
  reportError(err.message);
}
