// The wire protocol (docs/protocol.md) for the browser: a builder for every
// client → server message, parsing of the server's text messages and
// decoding of its binary frames. The names and numbers (message types, error
// codes, kinds, frame header offsets, limits) are not written here: they
// come from wire.js, which the daemon's Rust types write (see its head), and
// are re-exported so the page imports the protocol from one place. No DOM,
// no state: only the protocol.

import {
  CLIENT_MESSAGE, CONTACT_PHASE, FRAME_HEADER, FRAME_HEADER_BYTES, ROLE, SERVER_MESSAGE, PUPPETS_PATH,
} from './wire.js';

export * from './wire.js';

// ---------------------------------------------------------------- text messages

/** Whether a role may perform (send contacts, pins, poses, cursors, undo/redo/reset). */
export function canPerform(role) {
  return role === ROLE.PERFORMER || role === ROLE.DIRECTOR;
}

/** Whether a role may direct (record, play, paint, save, edit key poses, toggle replays, add, reorder and remove puppets). */
export function canDirect(role) {
  return role === ROLE.DIRECTOR;
}

/**
 * The keyframing pad is the unit square: pad points are [u, v] with both in
 * 0…1, v up (as stage coordinates, unlike the pad's canvas). The server
 * clamps cursors into it and refuses keys outside it.
 */
export const PAD_MIN = 0;
export const PAD_MAX = 1;

/** The pad's centre: where "+ key" puts a key while no cursor is down. */
export const PAD_CENTRE = Object.freeze([0.5, 0.5]);

/** The `owner` of this client's own contacts and pins, given the stage message's `client`. */
export function clientOwner(client) {
  return `client:${client}`;
}

// Builders, one per client → server message. Each returns the message as an
// object; `encodeClientMessage` turns it into the text sent.

/** The first message of every connection; `token` only when there is one (performers). */
export function helloMessage(role, token) {
  return token === undefined ? { type: CLIENT_MESSAGE.HELLO, role } : { type: CLIENT_MESSAGE.HELLO, role, token };
}

/** One input frame: `contacts` built with contactDown, contactMove, contactUp (each id at most once). */
export function contactsMessage(contacts) {
  return { type: CLIENT_MESSAGE.CONTACTS, contacts };
}

export function contactDown(id, x, y) {
  return { id, phase: CONTACT_PHASE.DOWN, x, y };
}

export function contactMove(id, x, y) {
  return { id, phase: CONTACT_PHASE.MOVE, x, y };
}

export function contactUp(id) {
  return { id, phase: CONTACT_PHASE.UP };
}

/** A pin at a stage point, on the topmost puppet there. */
export function pinMessage(x, y) {
  return { type: CLIENT_MESSAGE.PIN, x, y };
}

/**
 * "This part in front": where a puppet overlaps itself at the stage point,
 * the part behind comes in front until the overlap is undone.
 */
export function depthFlipMessage(x, y) {
  return { type: CLIENT_MESSAGE.DEPTH_FLIP, x, y };
}

/** Removes pin `handle` of `puppet` (the stage file's pins too). */
export function unpinMessage(puppet, handle) {
  return { type: CLIENT_MESSAGE.UNPIN, puppet, handle };
}

/**
 * One dab of the stiffness brush: strength above 1 stiffens, below 1
 * softens. Dabs of one `stroke` (a number per press of the brush) undo
 * together.
 */
export function paintMessage(puppet, x, y, radius, strength, stroke) {
  const message = { type: CLIENT_MESSAGE.PAINT, puppet, x, y, radius, strength };
  if (stroke !== undefined) message.stroke = stroke;
  return message;
}

/** A curve puppet from a stroke drawn on the page (director): stage points, width, "#RRGGBB". */
export function addCurveMessage(name, points, width, colour) {
  return { type: CLIENT_MESSAGE.ADD_CURVE, name, points, width, colour };
}

/** One dab of the depth-layer brush (director): triangles under it take `layer`, larger nearer. */
export function paintDepthMessage(puppet, x, y, radius, layer, stroke) {
  const message = { type: CLIENT_MESSAGE.PAINT_DEPTH, puppet, x, y, radius, layer };
  if (stroke !== undefined) message.stroke = stroke;
  return message;
}

/** Writes the puppet's painted weights to a new versioned file beside its mesh (director). */
export function saveWeightsMessage(puppet) {
  return { type: CLIENT_MESSAGE.SAVE_WEIGHTS, puppet };
}

/** Asks for a grid puppet's rest and deformed grid (answered with a `grid` message). */
export function exportGridMessage(puppet) {
  return { type: CLIENT_MESSAGE.EXPORT_GRID, puppet };
}

/** A skeleton's pose `t` of the way from key pose `from` to key pose `to`. */
export function poseMessage(puppet, from, to, t) {
  return { type: CLIENT_MESSAGE.POSE, puppet, from, to, t };
}

/** Starts recording a take (`name` may be left out: the next free take-NNN). */
export function recordMessage(name) {
  return name === undefined ? { type: CLIENT_MESSAGE.RECORD } : { type: CLIENT_MESSAGE.RECORD, name };
}

export function stopRecordingMessage() {
  return { type: CLIENT_MESSAGE.STOP_RECORDING };
}

/** Asks for the takes (answered with a `takes` message). */
export function listTakesMessage() {
  return { type: CLIENT_MESSAGE.LIST_TAKES };
}

/**
 * Plays take `take`; with `overdub`, records a new take of it and the live
 * hands. `replace` (regions from replaceRegion) and `replaceSources` (source
 * names) leave those contacts of the played take out, for the live hands to
 * redo; both are sent only when not empty, as the server writes them.
 */
export function playMessage(take, overdub = false, { replace = [], replaceSources = [] } = {}) {
  const message = { type: CLIENT_MESSAGE.PLAY, take, overdub };
  if (replace.length) message.replace = replace;
  if (replaceSources.length) message.replace_sources = replaceSources;
  return message;
}

/** A disc of a puppet's rest shape (stage coordinates of the rest mesh), for playMessage's `replace`. */
export function replaceRegion(puppet, at, radius) {
  return { puppet, at, radius };
}

export function stopPlayingMessage() {
  return { type: CLIENT_MESSAGE.STOP_PLAYING };
}

/**
 * A key pose of the puppet as it is now, at pad point `at` ([u, v]). `name`
 * may be left out (the server names it). A puppet's first key keys the
 * points its contacts hold, so something must hold the puppet then.
 */
export function keyAddMessage(puppet, at, name) {
  return name === undefined
    ? { type: CLIENT_MESSAGE.KEY_ADD, puppet, at }
    : { type: CLIENT_MESSAGE.KEY_ADD, puppet, name, at };
}

/** Moves key `key` (its index in the `keys` message) to pad point `at`. */
export function keyMoveMessage(puppet, key, at) {
  return { type: CLIENT_MESSAGE.KEY_MOVE, puppet, key, at };
}

/** Removes key `key` (its index in the `keys` message). */
export function keyDeleteMessage(puppet, key) {
  return { type: CLIENT_MESSAGE.KEY_DELETE, puppet, key };
}

/**
 * Moves the puppet's keyframing cursor to pad point `at`; with `at` left out
 * the cursor lets go and the puppet is free again.
 */
export function cursorMessage(puppet, at) {
  return at === undefined ? { type: CLIENT_MESSAGE.CURSOR, puppet } : { type: CLIENT_MESSAGE.CURSOR, puppet, at };
}

/** Writes the puppet's keys to its key file (answered with `keys_saved`). */
export function saveKeysMessage(puppet) {
  return { type: CLIENT_MESSAGE.SAVE_KEYS, puppet };
}

/** Asks for a `pong` with the same `t` (any role): the page measures its round trip with it. */
export function pingMessage(t) {
  return { type: CLIENT_MESSAGE.PING, t };
}

/** Undoes the puppet's last edit (a paint stroke, a pin, a pose). */
export function undoMessage(puppet) {
  return { type: CLIENT_MESSAGE.UNDO, puppet };
}

export function redoMessage(puppet) {
  return { type: CLIENT_MESSAGE.REDO, puppet };
}

/** The puppet as loaded: weights, the stage file's pins, pose at rest, key cursor off. */
export function resetMessage(puppet) {
  return { type: CLIENT_MESSAGE.RESET, puppet };
}

/**
 * Lets go of everything `source` holds (director): a sender that went
 * silent mid-touch, a stuck device, another page.
 */
export function releaseMessage(source) {
  return { type: CLIENT_MESSAGE.RELEASE, source };
}

/** Plays or pauses replay input `source` (director). */
export function replayMessage(source, playing) {
  return { type: CLIENT_MESSAGE.REPLAY, source, playing };
}

/**
 * Learn a MIDI mapping (director): the next control moved does `target`
 * ({action, puppet, poses, key, seconds} as an `[[input.map]]` entry has
 * them); without a target, stop waiting.
 */
export function midiLearnMessage(target) {
  return target === undefined ? { type: CLIENT_MESSAGE.MIDI_LEARN } : { type: CLIENT_MESSAGE.MIDI_LEARN, target };
}

/** Takes puppet `puppet` off the stage (director); its id is never used again. */
export function removePuppetMessage(puppet) {
  return { type: CLIENT_MESSAGE.REMOVE_PUPPET, puppet };
}

/** The stage's drawing order (director): every shown puppet's id once, bottom to top. */
export function orderPuppetsMessage(order) {
  return { type: CLIENT_MESSAGE.ORDER_PUPPETS, order };
}

export function encodeClientMessage(message) {
  return JSON.stringify(message);
}

/**
 * A server text message as an object, or null when the text is not a JSON
 * object. Its `type` is not checked: callers skip types they do not know
 * (they are for newer clients).
 */
export function parseServerMessage(text) {
  let message;
  try {
    message = JSON.parse(text);
  } catch {
    return null;
  }
  if (message === null || typeof message !== 'object') return null;
  return message;
}

// ---------------------------------------------------------------- adding a puppet (HTTP)

// A director adds a picture to the running stage with `POST /puppets?…`:
// the PNG's bytes as the body, the director's token as a bearer token. The
// answer is JSON: `puppet_added` (its `warnings` may say why the mesh is
// not what was hoped for) or an `error` as on the socket. Every page then
// gets a new `stage` message with the puppet in it.

/** `type` of the answer to a puppet that was added. */
export const PUPPET_ADDED = SERVER_MESSAGE.PUPPET_ADDED;

/**
 * The address to POST a picture to: `name` and `vertices` always; `x`, `y`
 * (stage coordinates) and `scale` only when given (the daemon's default:
 * the stage's centre, and a scale that fits the picture in half the stage).
 */
export function addPuppetPath({ name, vertices, x, y, scale, join }) {
  const query = new URLSearchParams({ name, vertices: String(vertices) });
  for (const [key, value] of Object.entries({ x, y, scale, join })) {
    if (value !== undefined && value !== null) query.set(key, String(value));
  }
  return `${PUPPETS_PATH}?${query}`;
}

// ---------------------------------------------------------------- binary frames

/**
 * The little-endian header (FRAME_HEADER) at the start of `buffer` (an ArrayBuffer):
 * {kind, puppet, sequence, inputTime, count, generation}, or null when the
 * buffer is shorter than a header. `kind` may be one this client does not
 * know. `generation` is the handle set's generation in handle frames (the
 * reserved u32, 0 in other kinds).
 */
export function decodeFrameHeader(buffer) {
  if (buffer.byteLength < FRAME_HEADER_BYTES) return null;
  const view = new DataView(buffer, 0, FRAME_HEADER_BYTES);
  return {
    kind: view.getUint32(FRAME_HEADER.KIND, true),
    puppet: view.getUint32(FRAME_HEADER.PUPPET, true),
    sequence: Number(view.getBigUint64(FRAME_HEADER.SEQUENCE, true)),
    inputTime: view.getFloat64(FRAME_HEADER.INPUT_TIME, true), // seconds since the daemon started
    count: view.getUint32(FRAME_HEADER.COUNT, true),
    generation: view.getUint32(FRAME_HEADER.GENERATION, true),
  };
}

/**
 * The frame's `header.count` points as x0, y0, x1, y1, … in stage
 * coordinates: a view into `buffer`, not a copy. Null when the buffer is too
 * short for them.
 */
export function framePoints(buffer, header) {
  if (buffer.byteLength < FRAME_HEADER_BYTES + 8 * header.count) return null;
  return new Float32Array(buffer, FRAME_HEADER_BYTES, 2 * header.count);
}

/**
 * A depth frame's `header.count` depths (a view into `buffer`), or null
 * when the buffer is too short for them.
 */
export function frameDepths(buffer, header) {
  if (buffer.byteLength < FRAME_HEADER_BYTES + 2 * header.count) return null;
  return new Uint16Array(buffer, FRAME_HEADER_BYTES, header.count);
}

/**
 * The triangle list `triangles` (flat vertex indices, three per triangle)
 * reordered back to front by `depths` (one per triangle), ties in mesh
 * order: drawn in this order, a part folded over another covers it whole.
 */
export function depthOrder(triangles, depths) {
  const n = depths.length;
  const order = Array.from({ length: n }, (_, i) => i);
  order.sort((a, b) => depths[a] - depths[b] || a - b);
  const out = new Array(3 * n);
  for (let k = 0; k < n; k++) {
    const t = order[k];
    out[3 * k] = triangles[3 * t];
    out[3 * k + 1] = triangles[3 * t + 1];
    out[3 * k + 2] = triangles[3 * t + 2];
  }
  return out;
}
