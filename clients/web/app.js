// puppetry web renderer: a thin client of the stream protocol (docs/protocol.md).
// Viewers draw the stage; performers also send their pointers as contacts.
// This module wires the page together: the connection (with reconnects),
// the state of the stage and its puppets, the status line, the main loop,
// the keyframing pad, and the `window.puppetry` test and debugging surface.

import {
  HANDLE_KIND, RIG_KIND, ROLE, SERVER_MESSAGE, FRAME_KIND_RIG, FRAME_KIND_VERTICES,
  clientOwner, decodeFrameHeader, encodeClientMessage, framePoints, helloMessage, parseServerMessage,
  listTakesMessage, playMessage, recordMessage, stopPlayingMessage, stopRecordingMessage,
} from './protocol.js';
import { MeshRenderer } from './renderer.js';
import { Overlay, keyHandleAnchor } from './overlay.js';
import { KeyPad } from './keypad.js';
import { PointerContacts, StageView } from './input.js';
import { PaintTool, PinTool, PoseSlider, ReplaceTool, TakeControls, calibrationInset, calibrationMarks } from './tools.js';

const params = new URLSearchParams(location.search);
const role = params.get('role') === ROLE.PERFORMER ? ROLE.PERFORMER : ROLE.VIEWER;
const token = params.get('token') ?? '';
const calibrateInset = calibrationInset(params);

const byId = (id) => document.getElementById(id);
const stageEl = byId('stage');
const glCanvas = byId('gl');
const overlayCanvas = byId('overlay');
const statusEl = byId('status');

// Test and debugging surface (see tests/web/drag.mjs, rigs.mjs, record.mjs and keypad.mjs).
const api = window.puppetry = {
  connected: false,
  framesReceived: 0,
  weightsReceived: 0,
  lastSequence: {},          // puppet id -> newest sequence number received
  rigFrames: 0,              // rig frames (grid handles, joints) received
  errors: [],                // server "error" messages and client-side failures
  stage: null,               // the last stage message
  keys: {},                  // puppet id -> the last "keys" message (key poses and the pad's cursor)
  handles: {},               // puppet id -> its handles now (stage message, then "handles" messages)
  ready: false,              // stage received and every texture settled
  stageToClient,
  snapshot,
  // lastGrid: the last "grid" message, once one came
  // take, takes: the last "take" message and the last "takes" list
  // export: the last "export" message (a take's export progress)
};

let cursors = [];            // mouse cursors on the stage, from "cursors" messages
let myOwner = '';            // "client:N", to tell our own handles apart
let puppets = [];            // state per puppet, in stage order (drawn bottom to top)
let needsDraw = true;
let needsOverlay = true;
let ws = null;               // the open (or opening) connection
let backoff = 500;           // ms before reconnecting, doubled per failed attempt up to 10 s
let lastError = '';          // the server's last "error" message on this connection

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

// ---------------------------------------------------------------- the page's parts

const view = new StageView(stageEl, [glCanvas, overlayCanvas]);

function stageToClient(x, y) {
  return view.stageToClient(x, y);
}

function clientToStage(cx, cy) {
  return view.clientToStage(cx, cy);
}

const renderer = new MeshRenderer(glCanvas, {
  onError: reportError,
  onTextureLoaded: () => { needsDraw = true; },
  onRestored: () => {
    needsDraw = true;
    setStatus('graphics context restored');
  },
});

// Draws now and reads the result back in the same task. For tests: RGBA
// bytes of the GL canvas alone, bottom row first.
function snapshot() {
  return renderer.snapshot();
}

const overlay = new Overlay(overlayCanvas, stageEl);

const currentPuppets = () => puppets;
const redrawOverlay = () => { needsOverlay = true; };

const pinTool = new PinTool(byId('pin-tool'), { puppets: currentPuppets, stageToClient, send });
const paintTool = new PaintTool({
  controls: byId('paint-controls'),
  button: byId('paint-tool'),
  radius: byId('paint-radius'),
  strength: byId('paint-strength'),
  save: byId('save-weights'),
}, { puppets: currentPuppets, clientToStage, send, reportError, onChange: redrawOverlay });
const poseSlider = new PoseSlider({
  controls: byId('pose-controls'),
  from: byId('pose-from'),
  to: byId('pose-to'),
  t: byId('pose-t'),
}, { send });

const takeControls = new TakeControls({
  controls: byId('take-controls'),
  record: byId('record'),
  state: byId('take-state'),
  list: byId('take-list'),
  play: byId('take-play'),
  overdub: byId('take-overdub'),
  stop: byId('take-stop'),
  format: byId('take-format'),
  download: byId('take-download'),
}, {
  send,
  messages: {
    record: recordMessage,
    stopRecording: stopRecordingMessage,
    listTakes: listTakesMessage,
    play: playMessage,
    stopPlaying: stopPlayingMessage,
  },
});

const keyPad = new KeyPad({
  panel: byId('keypad'),
  canvas: byId('keypad-canvas'),
  puppet: byId('keypad-puppet'),
  add: byId('key-add'),
  save: byId('save-keys'),
  letGo: byId('key-let-go'),
}, { send, canSend: () => api.connected });

const replaceTool = new ReplaceTool(byId('take-replace'), { puppets: currentPuppets, onChange: redrawOverlay });
takeControls.replaceTool = replaceTool;
api.replaceRegions = () => replaceTool.regions();

const pointerContacts = new PointerContacts(stageEl, view, {
  canStart: () => role === ROLE.PERFORMER && api.connected,
  tools: [replaceTool, paintTool, pinTool], // replace marking, then the brush, win over pinning
  onLifted: redrawOverlay,
});

if (role === ROLE.PERFORMER) {
  pinTool.enable();
  paintTool.enable();
  poseSlider.enable();
  takeControls.enable();
  replaceTool.enable();
  keyPad.enable();
}

function layout() {
  view.layout();
  needsDraw = needsOverlay = true;
  keyPad.dirty = true; // the device pixel ratio may have changed
}

addEventListener('resize', layout);

// ---------------------------------------------------------------- puppets

// A puppet as the stage message describes it, at rest until its first frame.
function puppetState(src) {
  return {
    id: src.id,
    src,                                    // its part of the stage message
    n: src.rest.length / 2,                 // vertices
    positions: new Float32Array(src.rest),  // newest vertex positions (stage coordinates)
    dirty: false,                           // positions not yet uploaded to the GPU
    texture: src.texture,
    handles: src.handles ?? [],
    // The rig as the stage describes it, and its newest points (deformed
    // grid handles or posed joints) from rig frames.
    rig: src.rig ?? { kind: RIG_KIND.FREE },
    rigPoints: src.rig?.rest ? new Float32Array(src.rig.rest.flat()) : null,
    // Per-triangle stiffness, shown while the paint tool is on.
    weights: src.weights ?? null,
    // Key handle id -> where on the mesh it is drawn (overlay.js keyHandleAnchor).
    keyAnchors: new Map(),
    framed: false,                          // a vertex frame has come
  };
}

// A puppet's new handle set. Key handles that stay keep their place on the
// mesh; new ones are pinned to it where they are now (see anchorKeyHandles).
function setHandles(p, handles) {
  p.handles = handles;
  api.handles[p.id] = handles;
  const kept = new Map();
  for (const h of handles) {
    const anchor = p.keyAnchors.get(h.id);
    if (anchor) kept.set(h.id, anchor);
  }
  p.keyAnchors = kept;
  anchorKeyHandles(p);
  needsOverlay = true;
}

// Pins key handles without a place yet to the mesh, so the overlay draws them
// moving with the cursor's blend. Not before the puppet's first frame: the
// rest positions are not where a handle's `at` is.
function anchorKeyHandles(p) {
  if (!p.framed) return;
  for (const h of p.handles) {
    if (h.kind !== HANDLE_KIND.KEY || p.keyAnchors.has(h.id)) continue;
    const anchor = keyHandleAnchor(h, p.positions, p.src.triangles);
    if (anchor) p.keyAnchors.set(h.id, anchor);
  }
}

const puppetById = (id) => puppets.find((q) => q.id === id);

// ---------------------------------------------------------------- connection

function send(message) {
  if (ws?.readyState === WebSocket.OPEN) ws.send(encodeClientMessage(message));
}

function connect() {
  const url = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`;
  setStatus(`connecting to ${url}…`);
  ws = new WebSocket(url);
  ws.binaryType = 'arraybuffer'; // frames are read in place as Float32Array views
  ws.onopen = () => send(role === ROLE.PERFORMER ? helloMessage(role, token) : helloMessage(role));
  ws.onmessage = (e) => (typeof e.data === 'string' ? onText(e.data) : onFrame(e.data));
  ws.onclose = () => {
    ws = null;
    api.connected = false;
    pointerContacts.reset(); // the server forgets our contacts with the connection
    const delay = backoff * (0.75 + Math.random() / 2); // jitter: clients don't return in lockstep
    backoff = Math.min(backoff * 2, 10000);
    setStatus(`disconnected${lastError ? ` (${lastError})` : ''}; retrying in ${(delay / 1000).toFixed(1)} s`, !!lastError);
    setTimeout(connect, delay);
  };
}

function onText(text) {
  const msg = parseServerMessage(text);
  if (!msg) return reportError('unreadable message from server');
  switch (msg.type) {
    case SERVER_MESSAGE.STAGE: return onStage(msg);
    case SERVER_MESSAGE.HANDLES: {
      const p = puppetById(msg.puppet);
      if (p) setHandles(p, msg.handles);
      return;
    }
    case SERVER_MESSAGE.KEYS:
      api.keys[msg.puppet] = msg;
      keyPad.onKeys(msg);
      return;
    case SERVER_MESSAGE.KEYS_SAVED:
      setStatus(`keys of puppet ${msg.puppet} saved to ${msg.file}`);
      return;
    case SERVER_MESSAGE.EXPORT:
      api.export = msg;
      takeControls.onExport(msg);
      return;
    case SERVER_MESSAGE.CURSORS:
      cursors = msg.cursors;
      needsOverlay = true;
      return;
    case SERVER_MESSAGE.WEIGHTS: {
      const p = puppetById(msg.puppet);
      if (p) { p.weights = msg.weights; needsOverlay = true; }
      api.weightsReceived++;
      return;
    }
    case SERVER_MESSAGE.WEIGHTS_SAVED:
      setStatus(`painted weights of puppet ${msg.puppet} saved to ${msg.file}`);
      return;
    case SERVER_MESSAGE.GRID:
      api.lastGrid = msg;
      return;
    case SERVER_MESSAGE.TAKE:
      api.take = msg;
      takeControls.onState(msg);
      return;
    case SERVER_MESSAGE.TAKES:
      api.takes = msg.takes;
      takeControls.onList(msg);
      return;
    case SERVER_MESSAGE.ERROR:
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
  view.size = msg.stage;
  myOwner = clientOwner(msg.client);
  backoff = 500;
  lastError = '';
  layout();
  puppets = msg.puppets.map(puppetState);
  api.keys = {};             // this connection's "keys" messages follow
  api.handles = {};
  for (const p of puppets) setHandles(p, p.handles);
  renderer.setStage(msg.stage, puppets).then(() => { api.ready = true; });
  poseSlider.setup(puppets);
  keyPad.setup(puppets);
  if (role === ROLE.PERFORMER) send(listTakesMessage());
  api.connected = true;
  setStatus(`connected as ${msg.role} (client ${msg.client}) · ${msg.puppets.length} puppet(s)`);
}

function onFrame(buf) {
  api.framesReceived++;
  const header = decodeFrameHeader(buf);
  if (!header) return reportError('short frame');
  if (header.kind === FRAME_KIND_RIG) return onRigFrame(header, buf);
  if (header.kind !== FRAME_KIND_VERTICES) return; // a newer kind
  const id = header.puppet;
  const p = puppetById(id);
  if (!p) return reportError(`frame for unknown puppet ${id}`);
  const points = header.count === p.n ? framePoints(buf, header) : null;
  if (!points) return reportError(`bad frame for puppet ${id}`);
  if (header.sequence <= (api.lastSequence[id] ?? -1)) return; // older than what we have
  api.lastSequence[id] = header.sequence;
  p.positions = points;
  p.dirty = true;
  if (!p.framed) { p.framed = true; anchorKeyHandles(p); }
  needsDraw = true;
  // The stiffness tint and the key handles follow the mesh.
  if (paintTool.on || p.keyAnchors.size) needsOverlay = true;
}

// A rig frame: the puppet's deformed grid handles or posed joints.
function onRigFrame(header, buf) {
  api.rigFrames++;
  const id = header.puppet;
  const p = puppetById(id);
  if (!p) return reportError(`rig frame for unknown puppet ${id}`);
  const points = framePoints(buf, header);
  if (!points) return reportError(`bad rig frame for puppet ${id}`);
  p.rigPoints = points;
  needsOverlay = true;
}

// ---------------------------------------------------------------- main loop

function drawOverlay() {
  overlay.draw({
    puppets,
    cursors,
    myOwner,
    ownContacts: pointerContacts.points(),
    showWeights: paintTool.on,
    brush: paintTool.outline(),
    replace: replaceTool.outlines(),
    calibrationMarks: calibrateInset !== null && api.stage ? calibrationMarks(calibrateInset, api.stage.stage) : null,
    stageToClient,
  });
}

// Per animation frame: at most one "contacts" message, one paint dab (on each
// puppet under the brush), one cursor message of the keyframing pad, and a
// redraw of what changed.
function tick() {
  requestAnimationFrame(tick);
  const message = pointerContacts.takeMessage();
  if (message) {
    send(message);
    needsOverlay = true;
  }
  paintTool.flush();
  keyPad.flush();
  if (needsDraw) { renderer.draw(); needsDraw = false; }
  if (needsOverlay) { drawOverlay(); needsOverlay = false; }
}

try {
  renderer.init();
  layout();
  connect();
  requestAnimationFrame(tick);
} catch (err) {
  reportError(err.message);
}
