// A stand-in for `puppetry serve`, to develop and test clients/web without the
// daemon: serves the page and a generated texture, and speaks docs/protocol.md
// with one quad puppet that follows the contact that grabbed it and moved
// last (any number may hold it: each handle is reported under its finger). It
// carries a two-joint skeleton with key poses (for the pose slider), and a
// replay input that does nothing but can be paused.
// A director adds puppets with `POST /puppets` (a PNG: checked for its
// signature and size, and warned about when every pixel is opaque) and
// removes or reorders them; added puppets are still pictures on a grid of
// about the vertices asked for, sized like the picture.
// It also checks what the page sends and answers violations with "error".
//
// Access as the stage file's [access] would give it: MOCK_TOKEN (default T)
// is an anonymous performer token; people with tokens "ana" (Ana,
// performer), "ben" (Ben, performer) and "director" (Dora, director). A
// wrong token gets error bad_token and close 4001.
//
//   PORT=8080 MOCK_TOKEN=T node mock-server.mjs   (PORT 0 or unset: any free port)
// Prints one JSON line {"url": …} when listening.

import { MAX_PICTURE_BYTES, PUPPET_VERTICES } from '../../clients/web/wire.js';
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { WebSocketServer } from 'ws';
import { describePng, encodePng } from './png.mjs';

const WEB = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../../clients/web');
const TOKEN = process.env.MOCK_TOKEN ?? 'T';
const started = process.hrtime.bigint();
const STAGE = { width: 800, height: 600 };
// Quad corners in stage coordinates (y-up): bottom-left, bottom-right, top-right, top-left.
const REST = [300, 200, 500, 200, 500, 400, 300, 400];
const UV = [0, 1, 1, 1, 1, 0, 0, 0]; // v down from the top of the picture
const TRIANGLES = [0, 1, 2, 0, 2, 3];
const JOINTS = [[400, 250], [400, 350]];
const POSES = ['rest', 'cheer', 'crouch'];
const PEOPLE = [
  { token: 'ana', name: 'Ana', role: 'performer' },
  { token: 'ben', name: 'Ben', role: 'performer' },
  { token: 'director', name: 'Dora', role: 'director' },
];
const PALETTE = ['#E69F00', '#56B4E9', '#009E73', '#F0E442', '#0072B2', '#D55E00', '#CC79A7'];
const REPLAY = 'mock-play';

// ---------------------------------------------------------------- texture

// Quadrants red (top left), green, blue, yellow, so a flipped or mirrored
// texture is obvious in a screenshot.
function texturePng(size = 64) {
  return encodePng(size, size, (x, y) => {
    const q = (y < size / 2 ? 0 : 2) + (x < size / 2 ? 0 : 1);
    const border = x < 3 || y < 3 || x >= size - 3 || y >= size - 3;
    return [...(border ? [0, 0, 0] : [[230, 40, 40], [40, 180, 60], [40, 80, 230], [240, 210, 30]][q]), 255];
  });
}
const TEXTURE = texturePng();

// ---------------------------------------------------------------- HTTP

const TYPES = { '.html': 'text/html', '.js': 'text/javascript', '.css': 'text/css' };
const server = http.createServer((req, res) => {
  const url = new URL(req.url, 'http://x');
  const texture = /^\/puppets\/(\d+)\/texture\.png$/.exec(url.pathname);
  if (texture) {
    const id = Number(texture[1]);
    const png = id === 0 ? TEXTURE : added.get(id)?.png;
    res.writeHead(png ? 200 : 404, png ? { 'content-type': 'image/png' } : {});
    return res.end(png);
  }
  if (url.pathname === '/puppets') {
    if (req.method === 'POST') return addPuppet(req, res, url.searchParams);
    res.writeHead(405, { allow: 'POST' });
    return res.end();
  }
  const name = url.pathname === '/' ? 'index.html' : url.pathname.slice(1);
  const file = path.join(WEB, name);
  if (name.includes('/') || !TYPES[path.extname(name)] || !fs.existsSync(file)) {
    res.writeHead(404);
    return res.end();
  }
  res.writeHead(200, { 'content-type': TYPES[path.extname(name)], 'cache-control': 'no-store' });
  res.end(fs.readFileSync(file));
});

// ---------------------------------------------------------------- puppets from the page

const VERTICES = { min: PUPPET_VERTICES.MIN, max: PUPPET_VERTICES.MAX };
const added = new Map(); // id -> {name, png, rest, uv, triangles, weights}: puppets added from the page
let lineup = [0];        // the ids on stage, bottom to top
let nextPuppet = 1;      // ids are never reused
const quadShown = () => lineup.includes(0);
const isQuad = (id) => id === 0 && quadShown();
const STILL_EDITS = ['paint', 'undo', 'redo', 'reset', 'pose'];

// `POST /puppets?name=…&vertices=…[&x=…&y=…&scale=…]`, the director's token
// as a bearer token, the PNG as the body.
function addPuppet(req, res, query) {
  const answer = (status, body) => {
    res.writeHead(status, { 'content-type': 'application/json' });
    res.end(JSON.stringify(body));
  };
  const refuse = (status, code, message, field) => {
    req.resume(); // the rest of the body is not wanted, but must not stall the answer
    answer(status, { type: 'error', code, message, ...(field ? { field } : {}) });
  };
  const token = /^Bearer (.*)$/.exec(req.headers.authorization ?? '')?.[1];
  const person = PEOPLE.find((p) => p.token === token) ?? (token === TOKEN ? { role: 'performer' } : null);
  if (!person) return refuse(401, 'bad_token', 'adding a puppet: token refused');
  if (person.role !== 'director') return refuse(403, 'forbidden', 'adding a puppet: not allowed for performers');
  const name = query.get('name')?.trim() ?? '';
  if (!name) return refuse(400, 'bad_request', 'name: a puppet needs a name', 'name');
  const vertices = Number(query.get('vertices'));
  if (!Number.isInteger(vertices) || vertices < VERTICES.min || vertices > VERTICES.max) {
    return refuse(400, 'out_of_range', `vertices: ${query.get('vertices')} is out of range (${VERTICES.min} to ${VERTICES.max})`, 'vertices');
  }
  const place = {};
  for (const key of ['x', 'y', 'scale']) {
    if (!query.has(key)) continue;
    const v = Number(query.get(key));
    if (!COORD(v) || (key === 'scale' && v <= 0)) return refuse(400, 'out_of_range', `${key}: ${query.get(key)} is out of range`, key);
    place[key] = v;
  }
  if ((req.headers['content-type'] ?? '').split(';')[0].trim() !== 'image/png') {
    return refuse(400, 'bad_request', 'the body must be a PNG (Content-Type: image/png)');
  }
  const chunks = [];
  let size = 0;
  let tooLarge = false;
  req.on('data', (data) => {
    size += data.length;
    if (size > MAX_PICTURE_BYTES) tooLarge = true;
    else chunks.push(data);
  });
  req.on('end', () => {
    if (tooLarge) return answer(413, { type: 'error', code: 'too_large', message: `the picture is over ${MAX_PICTURE_BYTES} bytes` });
    const png = Buffer.concat(chunks);
    const info = describePng(png);
    if (info.error) return answer(400, { type: 'error', code: 'bad_image', message: `${name}: ${info.error}` });
    const id = nextPuppet++;
    const spot = place.x === undefined && place.y === undefined ? freeSpot(info, place.scale) : {};
    const puppet = { name, png, ...gridMesh(info, vertices, { ...place, ...spot }) };
    added.set(id, puppet);
    lineup.push(id);
    const warnings = info.opaque
      ? [`${name}: every pixel is opaque (no transparent background), so the puppet is the whole ${info.width}×${info.height} rectangle; to mesh a figure's outline, cut it out onto a transparent background (PNG with alpha)`]
      : [];
    answer(200, {
      type: 'puppet_added', puppet: id, name, vertices: puppet.rest.length / 2, triangles: puppet.triangles.length / 3, warnings,
    });
    broadcastStage();
  });
}

// As the daemon places a picture given no x, y: where its box covers the
// puppets' boxes least, at its fit (half the stage) or smaller, nearest the
// middle (crates/daemon/src/stream/uploads.rs free_spot).
function freeSpot({ width, height }, scale) {
  const box = (rest) => {
    const xs = rest.filter((_, k) => k % 2 === 0), ys = rest.filter((_, k) => k % 2 === 1);
    return [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
  };
  const taken = lineup.map((id) => box(id === 0 ? REST : added.get(id).rest));
  const fit = scale ?? Math.min(STAGE.width / 2 / width, STAGE.height / 2 / height);
  let best = null;
  for (const shrink of scale === undefined ? [1, 0.75, 0.55, 0.35] : [1]) {
    const s = fit * shrink, hw = (width * s) / 2, hh = (height * s) / 2;
    for (let j = 0; j <= 8; j++) {
      for (let i = 0; i <= 8; i++) {
        const x = hw + ((STAGE.width - 2 * hw) * i) / 8, y = hh + ((STAGE.height - 2 * hh) * j) / 8;
        const covered = taken.reduce((sum, b) => sum + Math.max(0, Math.min(x + hw, b[2]) - Math.max(x - hw, b[0]))
          * Math.max(0, Math.min(y + hh, b[3]) - Math.max(y - hh, b[1])), 0);
        const off = Math.hypot(x - STAGE.width / 2, y - STAGE.height / 2);
        if (!best || covered < best.covered || (covered === best.covered && off < best.off)) best = { covered, off, x, y, scale: s };
      }
    }
    if (best.covered === 0) break;
  }
  return { x: best.x, y: best.y, scale: best.scale };
}

// The picture's rectangle as a grid of about `vertices` points, centred at
// x, y (default: the stage's centre), scaled to fit half the stage unless
// `scale` (stage units per pixel) says otherwise.
function gridMesh({ width, height }, vertices, { x = STAGE.width / 2, y = STAGE.height / 2, scale } = {}) {
  const s = scale ?? Math.min(STAGE.width / 2 / width, STAGE.height / 2 / height);
  const columns = Math.max(2, Math.round(Math.sqrt((vertices * width) / height)));
  const rows = Math.max(2, Math.round(vertices / columns));
  const rest = [];
  const uv = [];
  const triangles = [];
  for (let r = 0; r < rows; r++) {
    for (let c = 0; c < columns; c++) {
      const [u, v] = [c / (columns - 1), r / (rows - 1)];
      rest.push(x + (u - 0.5) * width * s, y + (v - 0.5) * height * s);
      uv.push(u, 1 - v); // v of the picture runs down from its top
      if (r && c) {
        const i = r * columns + c;
        triangles.push(i - columns - 1, i - columns, i, i - columns - 1, i, i - 1);
      }
    }
  }
  return { rest, uv, triangles, weights: new Array(triangles.length / 3).fill(1) };
}

// The stage as a client sees it, puppets bottom to top.
function stageMessage(c) {
  const you = c.role === 'viewer' ? { owner: c.person.owner, role: 'viewer' } : c.person;
  const puppets = lineup.map((id) => {
    if (id === 0) {
      return { id: 0, name: 'quad', texture: '/puppets/0/texture.png',
        rest: REST, uv: UV, triangles: TRIANGLES, handles: handles(), weights: [1, 1],
        rig: { kind: 'skeleton', mode: 'fk', bones: [[0, 1]], rest: JOINTS, poses: POSES } };
    }
    const { name, rest, uv, triangles, weights } = added.get(id);
    return { id, name, texture: `/puppets/${id}/texture.png`, rest, uv, triangles, handles: [], weights, rig: { kind: 'free' } };
  });
  return { type: 'stage', client: c.id, role: c.role, you, stage: STAGE, puppets };
}

// A new lineup: only the stage message, as the live state of the puppets
// that stay has not changed.
function broadcastStage() {
  for (const c of clients) if (c.ready) send(c, stageMessage(c));
}

// ---------------------------------------------------------------- stream

let positions = REST.slice();
let sequence = 0;
let nextClient = 1;
let nextHandle = 1;
let nextAnonymous = 1;
let generation = 0;
const grabs = new Map(); // "client:contact" -> {client, contact, handle, from, finger, start: positions}
let pins = [];   // {id, owner, kind: 'pin', at, grip}
let weights = [1, 1];
let pose = { puppet: 0, from: 'rest', to: 'cheer', t: 0 };
let replayPlaying = true;
// Edits that undo: snapshots of {pins, weights} before each edit (a paint
// stroke is one edit).
let undo = [];
let redo = [];
let lastStroke = null; // {client, stroke} of the paint stroke being made
const clients = new Set();

const handles = () => [...[...grabs.values()].map((g) => g.handle), ...pins];
const send = (c, message) => c.ws.send(JSON.stringify(message));
const broadcast = (data) => { for (const c of clients) if (c.ready) c.ws.send(data); };
const broadcastJson = (message) => broadcast(JSON.stringify(message));
const handlesMessage = () => ({ type: 'handles', puppet: 0, generation, handles: handles() });
const sendHandles = () => { generation++; broadcastJson(handlesMessage()); sendHandleFrame(); };
const historyMessage = () => ({ type: 'history', puppet: 0, undo: undo.length, redo: redo.length });
const inputsMessage = () => ({ type: 'inputs', replays: [{ name: REPLAY, playing: replayPlaying }] });
const inside = (x, y) => {
  if (!quadShown()) return false;
  const xs = positions.filter((_, i) => i % 2 === 0);
  const ys = positions.filter((_, i) => i % 2 === 1);
  return x >= Math.min(...xs) && x <= Math.max(...xs) && y >= Math.min(...ys) && y <= Math.max(...ys);
};

// Connected performers and directors, then the replay as a device.
function peopleMessage() {
  const list = [...clients].filter((c) => c.ready && c.role !== 'viewer').map((c) => c.person);
  list.push({ owner: REPLAY, name: REPLAY, role: 'device', colour: '#999999' });
  return { type: 'people', people: list };
}

// The first palette colour no connected person has.
function freeColour() {
  const used = new Set([...clients].filter((c) => c.ready && c.person).map((c) => c.person.colour));
  return PALETTE.find((c) => !used.has(c)) ?? PALETTE[clients.size % PALETTE.length];
}

function frame(kind, points, gen = 0, puppet = 0) {
  const n = points.length / 2;
  const buf = Buffer.alloc(32 + 8 * n);
  buf.writeUInt32LE(kind, 0);
  buf.writeUInt32LE(puppet, 4);
  buf.writeBigUInt64LE(BigInt(sequence), 8);
  buf.writeDoubleLE(Number(process.hrtime.bigint() - started) / 1e9, 16);
  buf.writeUInt32LE(n, 24);
  buf.writeUInt32LE(gen, 28);
  points.forEach((v, i) => buf.writeFloatLE(v, 32 + 4 * i));
  return buf;
}

// Where the handles are now: under their fingers (as if the solver met
// every hand), pins where they were put.
function handlePoints() {
  return [...[...grabs.values()].flatMap((g) => g.finger), ...pins.flatMap((h) => h.at)];
}

function sendHandleFrame() {
  if (handles().length) broadcast(frame(3, handlePoints(), generation));
}

function sendFrame() {
  ++sequence;
  broadcast(frame(1, positions));
  const [dx, dy] = [positions[0] - REST[0], positions[1] - REST[1]];
  broadcast(frame(2, JOINTS.flatMap(([x, y]) => [x + dx, y + dy])));
  sendHandleFrame();
}

const finite = (v) => typeof v === 'number' && Number.isFinite(v);
const COORD = (v) => finite(v) && Math.abs(v) <= 1e6;

// The edit about to happen can be undone: keep the state before it.
function remember() {
  undo.push({ pins: pins.slice(), weights: weights.slice() });
  redo = [];
}

function restore(state) {
  pins = state.pins.slice();
  weights = state.weights.slice();
  sendHandles();
  broadcastJson({ type: 'weights', puppet: 0, weights });
}

// What each role may send; a role missing from the list gets `forbidden`.
const ALLOWED = {
  ping: ['viewer', 'performer', 'director'],
  list_takes: ['viewer', 'performer', 'director'],
  contacts: ['performer', 'director'],
  pin: ['performer', 'director'],
  unpin: ['performer', 'director'],
  pose: ['performer', 'director'],
  undo: ['performer', 'director'],
  redo: ['performer', 'director'],
  reset: ['performer', 'director'],
  paint: ['director'],
  save_weights: ['director'],
  replay: ['director'],
  remove_puppet: ['director'],
  order_puppets: ['director'],
};

// Returns an error {code, message, field?}, or null when the input was fine.
function onInput(c, msg) {
  const allowed = ALLOWED[msg.type];
  if (!allowed) return { code: 'bad_message', message: `unknown message type ${JSON.stringify(msg.type)}` };
  if (!allowed.includes(c.role)) return { code: 'forbidden', message: `a ${c.role} may not send ${msg.type}` };
  // Puppets added from the page are still pictures: their edits change nothing.
  if (STILL_EDITS.includes(msg.type) && msg.puppet !== 0 && lineup.includes(msg.puppet)) return null;
  if (msg.type === 'ping') {
    send(c, { type: 'pong', t: msg.t });
    return null;
  }
  // The page asks for the takes on connecting; the mock has none.
  if (msg.type === 'list_takes') {
    send(c, { type: 'takes', takes: [] });
    return null;
  }
  if (msg.type === 'contacts') {
    if (!Array.isArray(msg.contacts)) return { code: 'bad_message', message: 'contacts: not an array' };
    const seen = new Set();
    for (const [i, e] of msg.contacts.entries()) {
      const bad = (message) => ({ code: 'bad_message', message: `contacts: ${message}` });
      if (!Number.isInteger(e?.id) || e.id < 0) return bad('bad id');
      if (seen.has(e.id)) return bad(`id ${e.id} twice in one frame`);
      seen.add(e.id);
      if (e.phase === 'down' || e.phase === 'move') {
        for (const k of ['x', 'y']) {
          if (!COORD(e[k])) return { code: 'out_of_range', message: 'coordinate out of range', field: `contacts[${i}].${k}` };
        }
      }
      if (e.phase === 'down') {
        if (c.down.has(e.id)) return bad(`id ${e.id} down twice`);
        c.down.add(e.id);
        if (inside(e.x, e.y)) {
          const handle = { id: nextHandle++, owner: c.person.owner, kind: 'contact', at: [e.x, e.y], grip: 'point' };
          grabs.set(`${c.id}:${e.id}`, { client: c, contact: e.id, handle, from: [e.x, e.y], finger: [e.x, e.y], start: positions.slice() });
          sendHandles();
        }
      } else if (e.phase === 'move') {
        if (!c.down.has(e.id)) return bad(`move of id ${e.id} that is not down`);
        const g = grabs.get(`${c.id}:${e.id}`);
        if (g) {
          g.finger = [e.x, e.y];
          const [dx, dy] = [e.x - g.from[0], e.y - g.from[1]];
          positions = g.start.map((v, k) => v + (k % 2 ? dy : dx));
          sendFrame();
        }
      } else if (e.phase === 'up') {
        if (!c.down.delete(e.id)) return bad(`up of id ${e.id} that is not down`);
        if (grabs.delete(`${c.id}:${e.id}`)) sendHandles();
      } else {
        return bad('bad phase');
      }
    }
    return null;
  }
  if (msg.type === 'pin') {
    for (const k of ['x', 'y']) if (!COORD(msg[k])) return { code: 'out_of_range', message: 'out of range', field: k };
    if (!inside(msg.x, msg.y)) return null; // empty stage: nothing to pin
    remember();
    pins.push({ id: nextHandle++, owner: c.person.owner, kind: 'pin', at: [msg.x, msg.y], grip: 'point' });
    sendHandles();
    broadcastJson(historyMessage());
    return null;
  }
  if (msg.type === 'unpin') {
    if (!isQuad(msg.puppet) || !pins.some((p) => p.id === msg.handle)) return { code: 'not_found', message: 'unpin: no such pin' };
    remember();
    pins = pins.filter((p) => p.id !== msg.handle);
    sendHandles();
    broadcastJson(historyMessage());
    return null;
  }
  if (msg.type === 'paint') {
    if (!isQuad(msg.puppet)) return { code: 'not_found', message: 'no such puppet' };
    for (const k of ['x', 'y']) if (!COORD(msg[k])) return { code: 'out_of_range', message: 'out of range', field: k };
    if (!(finite(msg.radius) && msg.radius > 0 && msg.radius <= Math.max(STAGE.width, STAGE.height))) {
      return { code: 'out_of_range', message: 'radius out of range', field: 'radius' };
    }
    if (!(finite(msg.strength) && msg.strength >= 0.1 && msg.strength <= 10)) {
      return { code: 'out_of_range', message: 'strength out of range', field: 'strength' };
    }
    // One undo step per stroke: a dab of a new stroke (or without one) starts a step.
    const same = msg.stroke !== undefined && lastStroke?.client === c && lastStroke.stroke === msg.stroke;
    if (!same) remember();
    lastStroke = msg.stroke === undefined ? null : { client: c, stroke: msg.stroke };
    // Triangles whose centroid the brush covers.
    weights = weights.map((w, t) => {
      const [a, b, d] = TRIANGLES.slice(3 * t, 3 * t + 3);
      const cx = (positions[2 * a] + positions[2 * b] + positions[2 * d]) / 3;
      const cy = (positions[2 * a + 1] + positions[2 * b + 1] + positions[2 * d + 1]) / 3;
      return Math.hypot(cx - msg.x, cy - msg.y) <= msg.radius ? w * msg.strength : w;
    });
    broadcastJson({ type: 'weights', puppet: 0, weights });
    if (!same) broadcastJson(historyMessage());
    return null;
  }
  if (msg.type === 'save_weights') {
    send(c, { type: 'weights_saved', puppet: 0, file: 'quad.v1.mesh.json' });
    return null;
  }
  if (msg.type === 'pose') {
    if (!isQuad(msg.puppet)) return { code: 'not_found', message: 'no such puppet' };
    if (!POSES.includes(msg.from) || !POSES.includes(msg.to)) return { code: 'not_found', message: 'no such key pose' };
    if (!(finite(msg.t) && msg.t >= 0 && msg.t <= 1)) return { code: 'out_of_range', message: 't out of range', field: 't' };
    pose = { puppet: 0, from: msg.from, to: msg.to, t: msg.t };
    broadcastJson({ type: 'pose', ...pose });
    return null;
  }
  if (msg.type === 'undo' || msg.type === 'redo') {
    if (!isQuad(msg.puppet)) return { code: 'not_found', message: 'no such puppet' };
    const [from, to] = msg.type === 'undo' ? [undo, redo] : [redo, undo];
    if (!from.length) return null;
    to.push({ pins: pins.slice(), weights: weights.slice() });
    lastStroke = null;
    restore(from.pop());
    broadcastJson(historyMessage());
    return null;
  }
  if (msg.type === 'reset') {
    if (!isQuad(msg.puppet)) return { code: 'not_found', message: 'no such puppet' };
    remember();
    lastStroke = null;
    restore({ pins: [], weights: [1, 1] });
    pose = { puppet: 0, from: 'rest', to: 'cheer', t: 0 };
    broadcastJson({ type: 'pose', ...pose });
    broadcastJson(historyMessage());
    return null;
  }
  if (msg.type === 'remove_puppet') {
    if (!lineup.includes(msg.puppet)) return { code: 'not_found', message: `remove_puppet: no puppet ${msg.puppet} on stage`, field: 'puppet' };
    const gone = added.get(msg.puppet);
    lineup = lineup.filter((id) => id !== msg.puppet);
    added.delete(msg.puppet);
    if (msg.puppet === 0) grabs.clear();
    broadcastStage();
    // A frame of it that was already on its way, as the daemon's may be:
    // pages drop it without a fuss.
    broadcast(frame(1, gone?.rest ?? positions, 0, msg.puppet));
    return null;
  }
  if (msg.type === 'order_puppets') {
    const order = msg.order;
    const everyOnce = Array.isArray(order) && order.length === lineup.length && new Set(order).size === order.length
      && order.every((id) => lineup.includes(id));
    if (!everyOnce) return { code: 'bad_message', message: `order_puppets: list every puppet on stage once (${lineup.join(', ')})`, field: 'order' };
    lineup = order.slice();
    broadcastStage();
    return null;
  }
  if (msg.type === 'replay') {
    if (msg.source !== REPLAY) return { code: 'not_found', message: `no replay ${msg.source}`, field: 'source' };
    replayPlaying = !!msg.playing;
    broadcastJson(inputsMessage());
    return null;
  }
  return { code: 'bad_message', message: `unhandled ${msg.type}` };
}

// Who a hello is: {role, person} or null when its token is refused.
function admit(c, msg) {
  if (msg.role === 'viewer') return { role: 'viewer', person: { owner: `client:${c.id}`, name: 'viewer', role: 'viewer', colour: '#999999' } };
  if (msg.role !== 'performer' && msg.role !== 'director') return null;
  const known = PEOPLE.find((p) => p.token === msg.token);
  if (known) return { role: known.role, person: { owner: `client:${c.id}`, name: known.name, role: known.role, colour: freeColour() } };
  if (msg.token === TOKEN) {
    return { role: 'performer', person: { owner: `client:${c.id}`, name: `performer ${nextAnonymous++}`, role: 'performer', colour: freeColour() } };
  }
  return null;
}

const wss = new WebSocketServer({ server, path: '/ws', maxPayload: 64 * 1024 });
wss.on('connection', (ws) => {
  const c = { ws, id: nextClient++, role: null, person: null, ready: false, down: new Set() };
  const fail = (error, close) => {
    ws.send(JSON.stringify({ type: 'error', ...error }));
    if (close) ws.close(...close);
  };
  ws.on('message', (data, isBinary) => {
    let msg;
    try {
      msg = isBinary ? null : JSON.parse(data.toString());
    } catch { /* handled below */ }
    if (!msg || typeof msg !== 'object') return fail({ code: 'bad_message', message: 'malformed message' }, c.ready ? null : [1008, 'bad message']);
    if (!c.ready) {
      if (msg.type !== 'hello') return fail({ code: 'hello', message: 'expected hello' }, [1008, 'expected hello']);
      const who = admit(c, msg);
      if (!who) {
        console.error(`mock: client ${c.id}: token refused (${msg.role})`);
        return fail({ code: 'bad_token', message: 'token refused' }, [4001, 'token refused']);
      }
      c.role = who.role;
      c.person = who.person;
      c.ready = true;
      clients.add(c);
      send(c, stageMessage(c));
      // The full live state, as the daemon sends a newcomer.
      if (quadShown()) {
        send(c, handlesMessage());
        send(c, { type: 'weights', puppet: 0, weights });
        send(c, historyMessage());
        send(c, { type: 'pose', ...pose });
      }
      for (const id of lineup) if (id !== 0) send(c, { type: 'history', puppet: id, undo: 0, redo: 0 });
      send(c, inputsMessage());
      if (c.role === 'viewer') send(c, peopleMessage());
      else broadcastJson(peopleMessage());
      if (quadShown() && positions.some((v, i) => v !== REST[i])) { sequence++; c.ws.send(frame(1, positions)); }
      if (quadShown() && handles().length) c.ws.send(frame(3, handlePoints(), generation));
      return;
    }
    const err = onInput(c, msg);
    if (err) {
      console.error(`mock: client ${c.id}: ${err.message}`);
      fail(err);
    }
  });
  ws.on('close', () => {
    const wasPerson = c.ready && c.role !== 'viewer';
    clients.delete(c);
    let held = false;
    for (const [k, g] of grabs) if (g.client === c) { grabs.delete(k); held = true; }
    if (held) sendHandles();
    if (wasPerson) broadcastJson(peopleMessage());
  });
});

server.listen(Number(process.env.PORT ?? 0), '127.0.0.1', () => {
  console.log(JSON.stringify({ url: `http://127.0.0.1:${server.address().port}/` }));
});
