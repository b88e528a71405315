// The wire protocol (docs/protocol.md), the browser's one mirror of the
// daemon's crates/daemon/src/protocol.rs: message type names, a builder for
// every client → server message, parsing of the server's text messages and
// decoding of its binary frames. No DOM, no state: only the protocol.

// ---------------------------------------------------------------- text messages

/** `type` of the messages a client sends. */
export const CLIENT_MESSAGE = Object.freeze({
  HELLO: 'hello',
  CONTACTS: 'contacts',
  PIN: 'pin',
  UNPIN: 'unpin',
  PAINT: 'paint',
  SAVE_WEIGHTS: 'save_weights',
  EXPORT_GRID: 'export_grid',
  POSE: 'pose',
  RECORD: 'record',
  STOP_RECORDING: 'stop_recording',
  LIST_TAKES: 'list_takes',
  PLAY: 'play',
  STOP_PLAYING: 'stop_playing',
  KEY_ADD: 'key_add',
  KEY_MOVE: 'key_move',
  KEY_DELETE: 'key_delete',
  CURSOR: 'cursor',
  SAVE_KEYS: 'save_keys',
});

/** `type` of the text messages the server sends. */
export const SERVER_MESSAGE = Object.freeze({
  STAGE: 'stage',
  HANDLES: 'handles',
  CURSORS: 'cursors',
  WEIGHTS: 'weights',
  WEIGHTS_SAVED: 'weights_saved',
  GRID: 'grid',
  TAKE: 'take',
  TAKES: 'takes',
  EXPORT: 'export',
  KEYS: 'keys',
  KEYS_SAVED: 'keys_saved',
  ERROR: 'error',
});

export const ROLE = Object.freeze({ VIEWER: 'viewer', PERFORMER: 'performer' });

export const CONTACT_PHASE = Object.freeze({ DOWN: 'down', MOVE: 'move', UP: 'up' });

/** A handle's `kind` (handles and stage messages). */
export const HANDLE_KIND = Object.freeze({ CONTACT: 'contact', PIN: 'pin', KEY: 'key' });

/** What a handle holds (`grip`, handles and stage messages); `grid` and `joint` come with an `index`. */
export const HANDLE_GRIP = Object.freeze({ POINT: 'point', GRID: 'grid', JOINT: 'joint' });

/** A puppet's `rig.kind` (stage message). */
export const RIG_KIND = Object.freeze({ FREE: 'free', GRID: 'grid', SKELETON: 'skeleton' });

/** The `owner` of the stage file's pins. */
export const CONFIG_OWNER = 'config';

/** The `owner` of the handles the keyframing cursor's blend of key poses holds. */
export const KEYS_OWNER = 'keys';

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

/** Removes pin `handle` of `puppet` (the stage file's pins too). */
export function unpinMessage(puppet, handle) {
  return { type: CLIENT_MESSAGE.UNPIN, puppet, handle };
}

/** One dab of the stiffness brush: strength above 1 stiffens, below 1 softens. */
export function paintMessage(puppet, x, y, radius, strength) {
  return { type: CLIENT_MESSAGE.PAINT, puppet, x, y, radius, strength };
}

/** Writes the puppet's painted weights back to its mesh file. */
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

// ---------------------------------------------------------------- binary frames

/** Every binary frame starts with a header of this many bytes, then f32 x, y pairs. */
export const FRAME_HEADER_BYTES = 32;

/** Frame kind: a puppet's deformed vertices. */
export const FRAME_KIND_VERTICES = 1;

/** Frame kind: a rigged puppet's deformed grid handles or posed joints. */
export const FRAME_KIND_RIG = 2;

/**
 * The 32-byte little-endian header at the start of `buffer` (an ArrayBuffer):
 * {kind, puppet, sequence, inputTime, count}, or null when the buffer is
 * shorter than a header. `kind` may be one this client does not know.
 */
export function decodeFrameHeader(buffer) {
  if (buffer.byteLength < FRAME_HEADER_BYTES) return null;
  const view = new DataView(buffer, 0, FRAME_HEADER_BYTES);
  return {
    kind: view.getUint32(0, true),
    puppet: view.getUint32(4, true),
    sequence: Number(view.getBigUint64(8, true)),
    inputTime: view.getFloat64(16, true), // seconds since the daemon started
    count: view.getUint32(24, true),
    // bytes 28..32 are reserved (0)
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
