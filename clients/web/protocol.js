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
  DEPTH_FLIP: 'depth_flip',
  UNPIN: 'unpin',
  PAINT: 'paint',
  PAINT_DEPTH: 'paint_depth',
  ADD_CURVE: 'add_curve',
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
  PING: 'ping',
  UNDO: 'undo',
  REDO: 'redo',
  RESET: 'reset',
  REPLAY: 'replay',
  REMOVE_PUPPET: 'remove_puppet',
  ORDER_PUPPETS: 'order_puppets',
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
  PEOPLE: 'people',
  HISTORY: 'history',
  POSE: 'pose',
  INPUTS: 'inputs',
  PONG: 'pong',
  LIVE: 'live',
});

/**
 * A connection's role (hello, stage and people messages): a `director` may
 * do everything, a `performer` perform, a `viewer` only watch. `device` is
 * the role of the stage's input sources in the people list.
 */
export const ROLE = Object.freeze({ VIEWER: 'viewer', PERFORMER: 'performer', DIRECTOR: 'director', DEVICE: 'device' });

/** Whether a role may perform (send contacts, pins, poses, cursors, undo/redo/reset). */
export function canPerform(role) {
  return role === ROLE.PERFORMER || role === ROLE.DIRECTOR;
}

/** Whether a role may direct (record, play, paint, save, edit key poses, toggle replays, add, reorder and remove puppets). */
export function canDirect(role) {
  return role === ROLE.DIRECTOR;
}

/** `code` of an `error` message. */
export const ERROR_CODE = Object.freeze({
  BAD_MESSAGE: 'bad_message',
  TOO_LARGE: 'too_large',
  BINARY: 'binary',
  FORBIDDEN: 'forbidden',
  BAD_TOKEN: 'bad_token',
  OUT_OF_RANGE: 'out_of_range',
  TOO_MANY: 'too_many',
  NOT_FOUND: 'not_found',
  BUSY: 'busy',
  FAILED: 'failed',
  HELLO: 'hello',
  // Answers of `POST /puppets` (adding a puppet) also use these:
  BAD_IMAGE: 'bad_image',
  BAD_REQUEST: 'bad_request',
});

/** Close frame codes the server closes with. */
export const CLOSE_CODE = Object.freeze({
  POLICY: 1008,          // origin refused
  TOO_LARGE: 1009,
  TRY_AGAIN_LATER: 1013, // too many connections
  TOKEN_REFUSED: 4001,
});

export const CONTACT_PHASE = Object.freeze({ DOWN: 'down', MOVE: 'move', UP: 'up' });

/** A handle's `kind` (handles and stage messages). */
export const HANDLE_KIND = Object.freeze({ CONTACT: 'contact', PIN: 'pin', KEY: 'key' });

/** What a handle holds (`grip`, handles and stage messages); `grid`, `joint` and `bone` come with an `index`. */
export const HANDLE_GRIP = Object.freeze({ POINT: 'point', GRID: 'grid', JOINT: 'joint', BONE: 'bone' });

/** A puppet's `rig.kind` (stage message). */
export const RIG_KIND = Object.freeze({ FREE: 'free', GRID: 'grid', SKELETON: 'skeleton', CURVE: 'curve' });

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

/** Plays or pauses replay input `source` (director). */
export function replayMessage(source, playing) {
  return { type: CLIENT_MESSAGE.REPLAY, source, playing };
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

/** The path puppets are added at. */
export const PUPPETS_PATH = '/puppets';

/** `type` of the answer to a puppet that was added. */
export const PUPPET_ADDED = 'puppet_added';

/** The vertex counts a new puppet's mesh may ask for, and the page's default. */
export const PUPPET_VERTICES = Object.freeze({ MIN: 50, MAX: 20000, DEFAULT: 1000 });

/** The largest picture the daemon takes (bytes). */
export const MAX_PICTURE_BYTES = 16 * 1024 * 1024;

/**
 * The address to POST a picture to: `name` and `vertices` always; `x`, `y`
 * (stage coordinates) and `scale` only when given (the daemon's default:
 * the stage's centre, and a scale that fits the picture in half the stage).
 */
export function addPuppetPath({ name, vertices, x, y, scale }) {
  const query = new URLSearchParams({ name, vertices: String(vertices) });
  for (const [key, value] of Object.entries({ x, y, scale })) {
    if (value !== undefined && value !== null) query.set(key, String(value));
  }
  return `${PUPPETS_PATH}?${query}`;
}

// ---------------------------------------------------------------- binary frames

/** Every binary frame starts with a header of this many bytes, then f32 x, y pairs. */
export const FRAME_HEADER_BYTES = 32;

/** Frame kind: a puppet's deformed vertices. */
export const FRAME_KIND_VERTICES = 1;

/** Frame kind: a rigged puppet's deformed grid handles or posed joints. */
export const FRAME_KIND_RIG = 2;

/**
 * Frame kind: where a puppet's handles are on the solved puppet, one point
 * per handle in the order of the `handles` message whose `generation` the
 * header's `generation` names.
 */
export const FRAME_KIND_HANDLES = 3;

/**
 * Frame kind: the depth of each triangle of a puppet (u16, larger is
 * nearer), `count` of them, padded to whole 4-byte words; sent when the
 * depth changes (a part folded over another).
 */
export const FRAME_KIND_DEPTH = 4;

/**
 * The 32-byte little-endian header at the start of `buffer` (an ArrayBuffer):
 * {kind, puppet, sequence, inputTime, count, generation}, or null when the
 * buffer is shorter than a header. `kind` may be one this client does not
 * know. `generation` is the handle set's generation in handle frames (the
 * reserved u32, 0 in other kinds).
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
    generation: view.getUint32(28, true),
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
