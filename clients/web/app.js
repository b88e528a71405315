// puppetry web renderer: a thin client of the stream protocol (docs/protocol.md).
// Viewers draw the stage; performers also send their pointers as contacts;
// directors get the tools that record, paint and save, and add, reorder and
// remove puppets. `?view=show` is the stage alone, for a projector or OBS's
// browser source.
// This module wires the page together: the connection (with reconnects,
// and the fall back to viewing when a token is refused), the state of the
// stage and its puppets (a new lineup mid-session keeps what the
// connection said about the puppets that stay), the toolbar, the main
// loop, the keyframing pad, and the `window.puppetry` test and debugging
// surface.

import {
  ERROR_CODE, CLOSE_CODE, FRAME_KIND, HANDLE_KIND,
  RIG_KIND, ROLE, SERVER_MESSAGE,
  canDirect, canPerform, clientOwner, decodeFrameHeader, depthOrder, encodeClientMessage, frameDepths, framePoints,
  helloMessage,
  listTakesMessage, parseServerMessage, pingMessage, playMessage, recordMessage, releaseMessage, stopPlayingMessage,
  stopRecordingMessage,
} from './protocol.js';
import { MeshRenderer } from './renderer.js';
import { Overlay, handleAt, keyHandleAnchor } from './overlay.js';
import { KeyPad } from './keypad.js';
import { PointerContacts, StageView } from './input.js';
import {
  CurveTool, EditControls, PaintTool, PinTool, PoseSlider, ReplaceTool, ReplayControls, TakeControls,
  calibrationInset, calibrationMarks,
} from './tools.js';
import { forgetToken, takeAccess, viewOptions } from './session.js';
import { People, holding } from './people.js';
import { FpsMeter, Hud, LatencyMeter } from './hud.js';
import { PuppetsPanel } from './puppets.js';
import { MidiLearn } from './midi.js';
import { DaemonClock, Soundtrack } from './soundtrack.js';

const params = new URLSearchParams(location.search);
const options = viewOptions(params);
const calibrateInset = calibrationInset(params);
// The role asked for and its token; the token leaves the address bar now.
const access = takeAccess(location, sessionStorage, (url) => history.replaceState(history.state, '', url), options);
let askedRole = access.role;  // the role the next hello asks for (viewer once a token was refused)
let role = ROLE.VIEWER;       // the role the server gave this connection

// How often the page measures its round trip to the daemon.
const PING_MS = 2000;
const TOKEN_REFUSED = 'token refused — viewing only';

const byId = (id) => document.getElementById(id);
const stageEl = byId('stage');
const glCanvas = byId('gl');
const overlayCanvas = byId('overlay');
const statusEl = byId('status');
const youSwatch = byId('you-swatch');
const legendEl = byId('people');

// Test and debugging surface (see tests/web/*.mjs).
const api = window.puppetry = {
  depth: {},
  connected: false,
  live: true,                // false while a relay says it lost the stage
  framesReceived: 0,
  weightsReceived: 0,
  weights: {},               // puppet id -> its per-triangle weights now
  lastSequence: {},          // puppet id -> newest sequence number received
  rigFrames: 0,              // rig frames (grid handles, joints) received
  handleFrames: 0,           // handle frames (where the handles are) received
  errors: [],                // server "error" messages and client-side failures
  stage: null,               // the last stage message
  you: null,                 // the stage message's `you`: {owner, name, role, colour}
  role,                      // the role the server gave (viewer until it did)
  people: [],                // the last people message's list
  peopleSeen: false,         // a people message came on this connection (the bar then holds everyone)
  keys: {},                  // puppet id -> the last "keys" message (key poses and the pad's cursor)
  handles: {},               // puppet id -> its handles now (stage message, then "handles" messages)
  history: {},               // puppet id -> the last "history" message
  pose: {},                  // puppet id -> the last "pose" message
  inputs: null,              // the last "inputs" message
  lastUpload: null,          // the daemon's answer to this page's last picture upload (puppet_added or error)
  uploads: 0,                // answers to picture uploads so far
  ready: false,              // stage received and every texture settled
  hellos: [],                // every hello sent: {role, token: bool}
  tokenRefused: false,       // the server refused the token; the page views only
  latency: null,             // median round trip of the last pings (ms), or null
  fps: null,                 // animation frames per second, or null
  view: options,
  stageToClient,
  clientToStage,
  snapshot,
  dots: () => overlay.drawn ?? [],   // what the overlay drew last: handles and cursors, in stage coordinates
  pads: () => overlay.padsDrawn ?? [], // the key pad areas the overlay drew last: {puppet, area}, stage coordinates
  rigLines: () => overlay.rigLines ?? [], // the grid lines the overlay drew last: {puppet, lines: [[x, y], …][]}, stage coordinates
  keyLabels: () => keyPad.labels ?? [], // the key pad's key names as drawn last: {text, x, y, w, h}, pad CSS px
  held: () => pointerContacts.held(), // pointers holding the stage now: contacts and tools' strokes
  poseShown: () => poseSlider.shown(),
  soundtrack: () => soundtrack.state(),
  positions: (id) => Array.from(puppetById(id)?.positions ?? []), // a puppet's vertices as drawn now
  rigPoints: (id) => Array.from(puppetById(id)?.rigPoints ?? []), // its grid handles or joints now, x y pairs
  drop: () => ws?.close(),           // closes the connection (it reconnects): for tests of the indicator
  // lastGrid: the last "grid" message, once one came
  // take, takes: the last "take" message and the last "takes" list
  // export: the last "export" message (a take's export progress)
};

let cursors = [];            // mouse cursors on the stage, from "cursors" messages
let myOwner = '';            // our owner string ("client:N"), to tell our own handles apart
let puppets = [];            // state per puppet, in stage order (drawn bottom to top)
let needsDraw = true;
let needsOverlay = true;
let ws = null;               // the open (or opening) connection
let backoff = 500;           // ms before reconnecting, doubled per failed attempt up to 10 s
let lastError = '';          // the server's last "error" message on this connection
let refusedNow = false;      // this connection's token was refused: reconnect as a viewer at once
let pingTimer = null;
let stageSeen = false;       // this connection had its stage: a later one is a new lineup of puppets
const people = new People();
const latency = new LatencyMeter(5);
const fpsMeter = new FpsMeter();

// ---------------------------------------------------------------- status

function setStatus(text, isError = false) {
  statusEl.textContent = text;
  statusEl.title = text; // the whole of it, where the bar cuts it short
  statusEl.classList.toggle('error', isError);
}

function reportError(message) {
  api.errors.push(message);
  if (api.errors.length > 50) api.errors.shift();
  setStatus(`error: ${message}`, true);
  console.warn('puppetry:', message);
}

// ---------------------------------------------------------------- the page's parts

if (options.show) document.body.classList.add('show');
if (options.transparent) document.documentElement.classList.add('transparent');

const hud = new Hud({
  bar: byId('bar'),
  connection: byId('connection'),
  banner: byId('banner'),
  bannerText: byId('banner-text'),
  bannerClose: byId('banner-close'),
  readout: byId('readout'),
  hideBar: byId('hide-bar'),
  showBar: byId('show-bar'),
  fullscreen: byId('fullscreen'),
}, { onLayout: () => barLayout(), chrome: [byId('keypad'), byId('hint')], keys: !options.show });

const view = new StageView(stageEl, [glCanvas, overlayCanvas], {
  fixedSize: options.size,
  top: () => (options.show ? 0 : hud.barHeight()),
});

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
}, { transparent: options.transparent });

// Draws now and reads the result back in the same task. For tests: RGBA
// bytes of the GL canvas alone, bottom row first.
function snapshot() {
  return renderer.snapshot();
}

const overlay = new Overlay(overlayCanvas, stageEl);

const currentPuppets = () => puppets;
const redrawOverlay = () => { needsOverlay = true; };

const pinTool = new PinTool(byId('pin-tool'), {
  puppets: currentPuppets, handleAt: (p, i) => handleAt(p, i, myOwner) ?? p.handles[i].at, stageToClient, send,
});
const paintTool = new PaintTool({
  controls: byId('paint-controls'),
  button: byId('paint-tool'),
  radius: byId('paint-radius'),
  strength: byId('paint-strength'),
  mode: byId('paint-mode'),
  layer: byId('paint-layer'),
  save: byId('save-weights'),
}, { puppets: currentPuppets, clientToStage, send, reportError, onChange: redrawOverlay });
const curveTool = new CurveTool({
  button: byId('curve-tool'),
  width: byId('curve-width'),
  colour: byId('curve-colour'),
}, { clientToStage, send, reportError, onChange: redrawOverlay });
const poseSlider = new PoseSlider({
  controls: byId('pose-controls'),
  from: byId('pose-from'),
  to: byId('pose-to'),
  t: byId('pose-t'),
}, { send });
const editControls = new EditControls(byId('edit-controls'), { send });
const replayControls = new ReplayControls(byId('replay-controls'), { send });
const daemonClock = new DaemonClock();
const soundtrack = new Soundtrack({ file: byId('soundtrack-file'), name: byId('soundtrack-name') }, daemonClock);
const midiLearn = new MidiLearn({
  controls: byId('midi-controls'),
  target: byId('midi-target'),
  learn: byId('midi-learn'),
  status: byId('midi-status'),
}, { send });

const takeControls = new TakeControls({
  controls: byId('take-controls'),
  record: byId('record'),
  state: byId('take-state'),
  list: byId('take-list'),
  play: byId('take-play'),
  overdub: byId('take-overdub'),
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
  token: () => access.token,
});

const keyPad = new KeyPad({
  panel: byId('keypad'),
  canvas: byId('keypad-canvas'),
  puppet: byId('keypad-puppet'),
  open: byId('keypad-open'),
  add: byId('key-add'),
  save: byId('save-keys'),
  letGo: byId('key-let-go'),
}, { send, canSend: () => api.connected });

const puppetsPanel = new PuppetsPanel({
  panel: byId('puppets-panel'),
  toggle: byId('puppets-toggle'),
  body: byId('puppets-body'),
  list: byId('puppet-list'),
  file: byId('puppet-file'),
  vertices: byId('puppet-vertices'),
  name: byId('puppet-name'),
  add: byId('puppet-add'),
  notice: byId('puppet-notice'),
  noticeText: byId('puppet-notice-text'),
  noticeClose: byId('puppet-notice-close'),
}, {
  send,
  token: () => access.token,
  onAnswer: (answer) => {
    api.lastUpload = answer;
    api.uploads++;
  },
  confirm: (text) => window.confirm(text),
});

const replaceTool = new ReplaceTool(byId('take-replace'), { puppets: currentPuppets, onChange: redrawOverlay });
takeControls.replaceTool = replaceTool;
api.replaceRegions = () => replaceTool.regions();

const pointerContacts = new PointerContacts(stageEl, view, {
  canStart: () => canPerform(role) && api.connected,
  tools: [replaceTool, curveTool, paintTool, pinTool], // replace marking, drawing, then the brush, win over pinning
  onLifted: (contact) => {
    redrawOverlay();
    layoutIfWaiting();
    if (contact && pointerContacts.held() === 0) sayLettingGo();
  },
});

// The first time a page's hands all let go, a hint says what a newcomer
// otherwise takes for a lost pose: a puppet let go springs back, and what
// keeps a pose (↶ undo stays grey: a drag is not an edit). It floats over
// the stage rather than in the status line: a long status wraps the
// toolbar, and the stage laid out again would move under the next touch.
const HINT_SECONDS = 12;
const hintEl = byId('hint');
let saidLettingGo = false;
function sayLettingGo() {
  if (saidLettingGo) return;
  saidLettingGo = true;
  hintEl.textContent = 'Let go, a puppet springs back to its rest pose (a drag is not an edit: ↶ undo has '
    + 'nothing to take back). To keep a pose, pin points while it is held (pin tool, or Shift+click pins).';
  hintEl.hidden = false;
  setTimeout(() => { hintEl.hidden = true; }, HINT_SECONDS * 1000);
}

// Shows the tools of `newRole` (the server's word on it) and hides the rest.
function applyRole(newRole) {
  role = newRole;
  api.role = newRole;
  const perform = !options.show && canPerform(newRole);
  const direct = !options.show && canDirect(newRole);
  pinTool.setEnabled(perform);
  poseSlider.setEnabled(perform);
  editControls.setEnabled(perform);
  keyPad.setMode({ perform, direct });
  paintTool.setEnabled(direct);
  curveTool.setEnabled(direct);
  replaceTool.setEnabled(direct);
  replayControls.setEnabled(direct);
  midiLearn.setEnabled(direct);
  takeControls.setRole({ perform, direct });
  puppetsPanel.setEnabled(direct);
  document.body.dataset.role = newRole;
}

applyRole(ROLE.VIEWER);

// The show view has no UI at all: not hidden, gone.
if (options.show) for (const id of ['bar', 'show-bar', 'keypad', 'banner']) byId(id).remove();

function layout() {
  view.layout();
  needsDraw = needsOverlay = true;
  keyPad.dirty = true; // the device pixel ratio may have changed
}

addEventListener('resize', layout);

// The toolbar wraps onto another line when a name joins the people list or
// a take starts, and the stage below it moves down. Under a performer's
// fingers that is a jump of the puppet they hold, or of a director's brush
// stroke or curve half drawn: while any pointer holds the stage, the new
// layout waits for the last lift (the bar may cover the stage's top edge
// meanwhile). A resized window lays out at once.
let layoutWaits = false;
function barLayout() {
  if (pointerContacts.held() > 0) {
    layoutWaits = true;
    return;
  }
  layout();
}

// Once nothing holds the stage (the last lift, a lost connection): the
// layout that waited.
function layoutIfWaiting() {
  if (layoutWaits && pointerContacts.held() === 0) {
    layoutWaits = false;
    layout();
  }
}

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
    handlesGeneration: src.generation ?? null, // the handle set's generation (handles messages)
    handleFrame: null,                      // {generation, sequence, points}: the newest handle frame
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
function setHandles(p, handles, generation) {
  p.handles = handles;
  p.handlesGeneration = generation ?? null;
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
// moving with the cursor's blend until handle frames say where they are.
// Not before the puppet's first frame: the rest positions are not where a
// handle's `at` is.
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
  refusedNow = false;
  stageSeen = false;
  const socket = new WebSocket(url);
  ws = socket;
  socket.binaryType = 'arraybuffer'; // frames are read in place as Float32Array views
  socket.onopen = () => {
    // The token goes in the hello and nowhere else.
    const withToken = askedRole !== ROLE.VIEWER;
    api.hellos.push({ role: askedRole, token: withToken && !!access.token });
    send(withToken ? helloMessage(askedRole, access.token) : helloMessage(askedRole));
  };
  socket.onmessage = (e) => (typeof e.data === 'string' ? onText(e.data) : onFrame(e.data));
  socket.onclose = (e) => onClose(e);
}

function onClose(e) {
  ws = null;
  api.connected = false;
  clearInterval(pingTimer);
  latency.clear();
  pointerContacts.reset(); // the server forgets our contacts with the connection
  layoutIfWaiting();
  if (refusedNow || e.code === CLOSE_CODE.TOKEN_REFUSED) {
    // Asking again with the same token cannot help: view at once, say why.
    refuseToken();
    hud.setConnection(false, 'token refused — reconnecting as a viewer…');
    connect();
    return;
  }
  const delay = backoff * (0.75 + Math.random() / 2); // jitter: clients don't return in lockstep
  backoff = Math.min(backoff * 2, 10000);
  const why = lastError || e.reason || (e.code && e.code !== 1000 && e.code !== 1005 && e.code !== 1006 ? `code ${e.code}` : '');
  const text = `disconnected${why ? ` (${why})` : ''}; retrying in ${(delay / 1000).toFixed(1)} s`;
  setStatus(text, !!why);
  hud.setConnection(false, text);
  setTimeout(connect, delay);
}

// The server refused our token: from now on this page is a viewer, and the
// token is forgotten and the role dropped from the address (a reload is a
// viewer, and does not send it again).
function refuseToken() {
  if (askedRole !== ROLE.VIEWER) {
    askedRole = ROLE.VIEWER;
    access.token = '';
    forgetToken(sessionStorage);
    const url = new URL(location.href);
    url.searchParams.delete('role');
    history.replaceState(history.state, '', url);
  }
  api.tokenRefused = true;
  applyRole(ROLE.VIEWER);
  hud.setNotice(TOKEN_REFUSED, 'refused');
}

// The live state kept per puppet.
const PER_PUPPET = new Set([
  SERVER_MESSAGE.HANDLES, SERVER_MESSAGE.HISTORY, SERVER_MESSAGE.POSE, SERVER_MESSAGE.KEYS, SERVER_MESSAGE.WEIGHTS,
]);

function onText(text) {
  const msg = parseServerMessage(text);
  if (!msg) return reportError('unreadable message from server');
  // A message about one puppet that is not on stage was sent before a
  // director removed it: it says nothing about the stage now.
  if (PER_PUPPET.has(msg.type) && !puppetById(msg.puppet)) return;
  switch (msg.type) {
    case SERVER_MESSAGE.STAGE: return onStage(msg);
    case SERVER_MESSAGE.HANDLES:
      setHandles(puppetById(msg.puppet), msg.handles, msg.generation);
      renderLegend();
      return;
    case SERVER_MESSAGE.PEOPLE:
      people.update(msg.people);
      api.people = people.list;
      api.peopleSeen = true;
      renderLegend();
      showYou();
      needsOverlay = true;
      return;
    case SERVER_MESSAGE.HISTORY:
      api.history[msg.puppet] = msg;
      editControls.onHistory(msg);
      return;
    case SERVER_MESSAGE.POSE:
      api.pose[msg.puppet] = msg;
      poseSlider.onPose(msg);
      return;
    case SERVER_MESSAGE.INPUTS:
      api.inputs = msg;
      replayControls.onInputs(msg);
      midiLearn.onInputs(msg);
      return;
    case SERVER_MESSAGE.LIVE:
      // A relay lost (or found again) the stage it shows.
      api.live = msg.live;
      hud.setConnection(msg.live, msg.live ? 'connected' : (msg.reason || 'the stage is not reachable'));
      return;
    case SERVER_MESSAGE.PONG:
      if (typeof msg.t === 'number') {
        latency.add(performance.now() - msg.t);
        daemonClock.onPong(msg.t, performance.now(), msg.clock);
        api.latency = latency.ms;
        hud.setReadout(api.latency, api.fps);
      }
      return;
    case SERVER_MESSAGE.KEYS:
      api.keys[msg.puppet] = msg;
      keyPad.onKeys(msg);
      if (puppetById(msg.puppet)?.src.pads?.length) needsOverlay = true; // it draws the pad's keys and cursor
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
      puppetById(msg.puppet).weights = msg.weights;
      needsOverlay = true;
      api.weights[msg.puppet] = msg.weights;
      api.weightsReceived++;
      return;
    }
    case SERVER_MESSAGE.WEIGHTS_SAVED:
      api.weightsSaved = msg;
      setStatus(`painted weights of puppet ${msg.puppet} saved to ${msg.file}`);
      return;
    case SERVER_MESSAGE.GRID:
      api.lastGrid = msg;
      return;
    case SERVER_MESSAGE.TAKE:
      api.take = msg;
      takeControls.onState(msg);
      soundtrack.onTake(msg);
      return;
    case SERVER_MESSAGE.TAKES:
      api.takes = msg.takes;
      takeControls.onList(msg);
      return;
    case SERVER_MESSAGE.ERROR:
      if (msg.code === ERROR_CODE.BAD_TOKEN) {
        // Not a fault of the page: the close (4001) that follows reconnects as a viewer.
        refusedNow = true;
        refuseToken();
        return;
      }
      lastError = msg.field ? `${msg.message} (${msg.field})` : msg.message;
      return reportError(lastError);
    default:
      return; // unknown kinds are for newer clients
  }
}

// The people list, with who holds contacts now (a director may let any
// holder but itself go: a sender gone silent mid-touch).
function renderLegend() {
  const held = holding(api.handles);
  const release = !options.show && canDirect(role) ? (owner) => send(releaseMessage(owner)) : null;
  const key = JSON.stringify([api.people, [...held], Boolean(release), myOwner]);
  if (key === legendKey) return; // handles messages come at input rate
  legendKey = key;
  people.renderLegend(legendEl, myOwner, held, release);
}
let legendKey = '';

// "you" in the status line: name, role and colour swatch.
function showYou() {
  const s = api.stage;
  if (!s) return;
  const me = people.get(myOwner) ?? api.you;
  const who = me?.name && me.name !== role ? `${me.name} · ${role}` : role;
  setStatus(`${who} · ${s.puppets.length} puppet${s.puppets.length === 1 ? '' : 's'}`);
  youSwatch.hidden = !me?.colour;
  if (me?.colour) youSwatch.style.backgroundColor = me.colour;
}

// The first stage message of a connection sets everything up; a later one
// (a director added, removed or reordered puppets) is a new lineup on the
// same connection. Either way every part of the page is set up again from
// it, once: nothing here adds listeners or timers of its own.
function onStage(msg) {
  const lineup = stageSeen;
  stageSeen = true;
  api.stage = msg;
  api.you = msg.you ?? null;
  api.ready = false;
  view.size = msg.stage;
  myOwner = msg.you?.owner ?? clientOwner(msg.client);
  applyRole(msg.you?.role ?? msg.role ?? ROLE.VIEWER);
  layout();
  const before = new Map(puppets.map((p) => [p.id, p]));
  puppets = msg.puppets.map((src) => (lineup ? keptPuppet(before.get(src.id), src) : null) ?? puppetState(src));
  if (lineup) {
    // What this connection heard about the puppets that stay is still
    // true and is not sent again; what it heard about the ones gone goes.
    const shown = new Set(puppets.map((p) => String(p.id)));
    for (const table of [api.lastSequence, api.keys, api.handles, api.history, api.pose, api.weights, api.depth]) {
      for (const id of Object.keys(table)) if (!shown.has(id)) delete table[id];
    }
    for (const p of puppets) if (!before.has(p.id)) api.weights[p.id] = p.weights;
  } else {
    api.lastSequence = {}; // a restarted daemon counts from the start again
    api.keys = {};         // this connection's "keys", "history", "pose" and "people" messages follow
    api.handles = {};
    api.history = {};
    api.pose = {};
    api.depth = {};        // per puppet: the newest depth frame's generation and depths
    api.weights = Object.fromEntries(puppets.map((p) => [p.id, p.weights]));
    people.clear();
    api.peopleSeen = false;
  }
  for (const p of puppets) setHandles(p, p.handles, p.handlesGeneration);
  renderer.setStage(msg.stage, puppets).then(() => { api.ready = true; });
  poseSlider.setup(puppets);
  midiLearn.setup(msg.puppets);
  keyPad.setup(puppets, { sameConnection: lineup });
  editControls.setup(puppets);
  puppetsPanel.setup(puppets);
  paintTool.setStage(msg.stage);
  if (lineup) {
    const pose = api.pose[poseSlider.puppet];
    if (pose) poseSlider.onPose(pose);
    // A puppet added just now has no edits yet (a history message, if one comes, says so too).
    for (const p of puppets) editControls.onHistory(api.history[p.id] ?? { puppet: p.id, undo: 0, redo: 0 });
    showYou();
    return;
  }
  backoff = 500;
  lastError = '';
  send(listTakesMessage());
  api.connected = true;
  showYou();
  hud.setConnection(true, 'connected');
  // The round trip, now and every few seconds.
  clearInterval(pingTimer);
  const ping = () => send(pingMessage(performance.now()));
  ping();
  pingTimer = setInterval(ping, PING_MS);
}

// A puppet of the previous lineup that is still on stage, brought over
// with its pose, handles and painted weights (the stage message describes
// it as loaded); null when it is new, or not the same mesh after all.
function keptPuppet(p, src) {
  if (!p || p.n !== src.rest.length / 2) return null;
  p.src = src;
  p.texture = src.texture;
  return p;
}

function onFrame(buf) {
  api.framesReceived++;
  const header = decodeFrameHeader(buf);
  if (!header) return reportError('short frame');
  if (header.kind === FRAME_KIND.RIG) return onRigFrame(header, buf);
  if (header.kind === FRAME_KIND.HANDLES) return onHandleFrame(header, buf);
  if (header.kind === FRAME_KIND.DEPTH) return onDepthFrame(header, buf);
  if (header.kind !== FRAME_KIND.VERTICES) return; // a newer kind
  const id = header.puppet;
  const p = puppetById(id);
  // Puppet ids are never reused: a frame of a puppet not on stage was on its
  // way when a director removed it. Nothing to draw, nothing wrong.
  if (!p) return;
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
  if (!p) return; // a removed puppet's (see onFrame)
  const points = framePoints(buf, header);
  if (!points) return reportError(`bad rig frame for puppet ${id}`);
  p.rigPoints = points;
  needsOverlay = true;
}

// A handle frame: where each handle of a generation of the puppet's handle
// set is on the solved puppet. Drawn once the handles message of that
// generation is here (see overlay.js handleAt).
function onHandleFrame(header, buf) {
  api.handleFrames++;
  const p = puppetById(header.puppet);
  if (!p) return; // a removed puppet's (see onFrame)
  const points = framePoints(buf, header);
  if (!points) return reportError(`bad handle frame for puppet ${header.puppet}`);
  const old = p.handleFrame;
  if (old && old.generation === header.generation && header.sequence < old.sequence) return; // older
  p.handleFrame = { generation: header.generation, sequence: header.sequence, points };
  needsOverlay = true;
}

// A depth frame: the puppet's triangles are drawn back to front in this
// order from now on, so a part folded over another covers it whole.
function onDepthFrame(header, buf) {
  const p = puppetById(header.puppet);
  if (!p) return; // a removed puppet's (see onFrame)
  const depths = header.count === p.src.triangles.length / 3 ? frameDepths(buf, header) : null;
  if (!depths) return reportError(`bad depth frame for puppet ${header.puppet}`);
  p.drawOrder = depthOrder(p.src.triangles, depths);
  api.depth[header.puppet] = { generation: header.generation, depths: Array.from(depths) };
  needsDraw = true;
}

// ---------------------------------------------------------------- main loop

function drawOverlay() {
  overlay.draw({
    puppets,
    cursors,
    myOwner,
    ownContacts: options.show ? [] : pointerContacts.points(),
    colour: (owner, alpha) => people.css(owner, alpha),
    rigs: !options.show,
    handles: options.dots,
    showWeights: paintTool.on,
    pads: options.show ? [] : padAreas(),
    brush: paintTool.outline(),
    sketch: curveTool.sketch(),
    replace: replaceTool.outlines(),
    calibrationMarks: calibrateInset !== null && api.stage ? calibrationMarks(calibrateInset, api.stage.stage) : null,
    stageToClient,
  });
}

// The stage file's key pad areas (docs/keyframing.md), with what each
// drives: the overlay draws them, since a contact there moves a cursor.
function padAreas() {
  return puppets.flatMap((p) => (p.src.pads ?? []).map((pad) => ({
    ...pad, puppet: p.id, name: p.src.name, keys: api.keys[p.id]?.keys, cursor: api.keys[p.id]?.cursor,
  })));
}

// Per animation frame: at most one "contacts" message, one paint dab (on each
// puppet under the brush), one cursor message of the keyframing pad, and a
// redraw of what changed.
function tick(now) {
  requestAnimationFrame(tick);
  if (fpsMeter.tick(now)) {
    api.fps = fpsMeter.fps;
    hud.setReadout(api.latency, api.fps);
  }
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
  hud.setConnection(false, 'connecting…', { loud: false });
  connect();
  requestAnimationFrame(tick);
} catch (err) {
  reportError(err.message);
}
