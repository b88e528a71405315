// GENERATED from the Rust types in crates/protocol/src/lib.rs by
// crates/daemon/src/javascript.rs: do not edit. To rewrite it, run
//   cargo test --release -p puppetry-daemon --lib wire
// (the test writes this file and fails when it was out of date).
// clients/web/protocol.js re-exports these names with the builders.

// ---------------------------------------------------------------- text messages

/** `type` of the messages a client sends (`ClientMessage`). */
export const CLIENT_MESSAGE = Object.freeze({
  HELLO: 'hello',
  CONTACTS: 'contacts',
  PIN: 'pin',
  DEPTH_FLIP: 'depth_flip',
  UNPIN: 'unpin',
  PAINT: 'paint',
  PAINT_DEPTH: 'paint_depth',
  ADD_CURVE: 'add_curve',
  UNDO: 'undo',
  REDO: 'redo',
  RESET: 'reset',
  RELEASE: 'release',
  REPLAY: 'replay',
  SAVE_WEIGHTS: 'save_weights',
  EXPORT_GRID: 'export_grid',
  POSE: 'pose',
  RECORD: 'record',
  STOP_RECORDING: 'stop_recording',
  LIST_TAKES: 'list_takes',
  PLAY: 'play',
  STOP_PLAYING: 'stop_playing',
  REMOVE_PUPPET: 'remove_puppet',
  ORDER_PUPPETS: 'order_puppets',
  CURSOR: 'cursor',
  KEY_ADD: 'key_add',
  KEY_MOVE: 'key_move',
  KEY_DELETE: 'key_delete',
  SAVE_KEYS: 'save_keys',
  PING: 'ping',
  MIDI_LEARN: 'midi_learn',
});

/** `type` of the text messages the server sends (`ServerMessage`). */
export const SERVER_MESSAGE = Object.freeze({
  STAGE: 'stage',
  PEOPLE: 'people',
  PONG: 'pong',
  LIVE: 'live',
  HANDLES: 'handles',
  HISTORY: 'history',
  POSE: 'pose',
  INPUTS: 'inputs',
  CURSORS: 'cursors',
  WEIGHTS: 'weights',
  WEIGHTS_SAVED: 'weights_saved',
  GRID: 'grid',
  KEYS: 'keys',
  KEYS_SAVED: 'keys_saved',
  PUPPET_ADDED: 'puppet_added',
  TAKE: 'take',
  EXPORT: 'export',
  TAKES: 'takes',
  ERROR: 'error',
});

/** A connection's role (hello, stage and people messages): a `director` may do everything, a `performer` perform, a `viewer` only watch. `device` is the role of the stage's input sources in the people list (`PersonRole`). */
export const ROLE = Object.freeze({
  /** Watches only. */
  VIEWER: 'viewer',
  /** Performs: contacts, pins, poses, cursors (maybe on some puppets). */
  PERFORMER: 'performer',
  /** Everything a performer does, and takes, painting, saving, key poses. */
  DIRECTOR: 'director',
  /** One of the stage's own input sources (a touch table, a pad, a replay). */
  DEVICE: 'device',
});

/** `code` of an `error` message, also in the answers of `POST /puppets` (`ErrorCode`). */
export const ERROR_CODE = Object.freeze({
  /** Not JSON, or not a message of the protocol. */
  BAD_MESSAGE: 'bad_message',
  /** Longer than 64 KiB. */
  TOO_LARGE: 'too_large',
  /** A binary message (clients send text). */
  BINARY: 'binary',
  /** The client's role may not send this message (or not for this puppet). */
  FORBIDDEN: 'forbidden',
  /** The hello's token is not one of the stage's. */
  BAD_TOKEN: 'bad_token',
  /** A number is not finite or is too large (coordinates: |v| ≤ 1e6). */
  OUT_OF_RANGE: 'out_of_range',
  /** More than the resource budget allows (`docs/limits.md`): contacts in one message, or held down at once. */
  TOO_MANY: 'too_many',
  /** No such puppet, take, key, handle… */
  NOT_FOUND: 'not_found',
  /** Something else is running (a take, an export). */
  BUSY: 'busy',
  /** An action that failed (a file that could not be written, …). */
  FAILED: 'failed',
  /** The first message was not a hello. */
  HELLO: 'hello',
  /** An uploaded picture is not a PNG, or cannot be made a puppet. */
  BAD_IMAGE: 'bad_image',
  /** An HTTP request's parameters are missing or not well-formed. */
  BAD_REQUEST: 'bad_request',
});

/** A contact's `phase` (`Phase`). */
export const CONTACT_PHASE = Object.freeze({
  DOWN: 'down',
  MOVE: 'move',
  UP: 'up',
});

/** A handle's `kind` (handles and stage messages; `HandleKind`). */
export const HANDLE_KIND = Object.freeze({
  /** Held by a finger, mouse or pen (a client's or an input source's). */
  CONTACT: 'contact',
  /** Held by a pin (the stage file's or one placed since). */
  PIN: 'pin',
  /** Held by the keyframing cursor's blend of key poses. */
  KEY: 'key',
});

/** What a handle holds (`grip`, handles and stage messages); `grid`, `joint` and `bone` come with an `index` (`GripKind`). */
export const HANDLE_GRIP = Object.freeze({
  /** A material point of the mesh. */
  POINT: 'point',
  /** A grid handle of a grid puppet. */
  GRID: 'grid',
  /** A joint of a skeleton puppet. */
  JOINT: 'joint',
  /** A point on a skeleton puppet's bone (`index`: the bone). */
  BONE: 'bone',
});

/** A puppet's `rig.kind` (stage message; `RigDescription`). */
export const RIG_KIND = Object.freeze({
  FREE: 'free',
  GRID: 'grid',
  SKELETON: 'skeleton',
  CURVE: 'curve',
});

/** The `owner` of the stage file's pins. */
export const CONFIG_OWNER = 'config';

/** The `owner` of the handles the keyframing cursor's blend of key poses holds. */
export const KEYS_OWNER = 'keys';

/** The longest text message a client may send (bytes); longer ones close the connection with `CLOSE_CODE.TOO_LARGE`. */
export const MAX_CLIENT_MESSAGE_BYTES = 65536;

/** Contacts one `contacts` message may carry, and contacts one client may hold down. */
export const MAX_CONTACTS_PER_MESSAGE = 40;

/** Close frame codes the server closes with. */
export const CLOSE_CODE = Object.freeze({
  /** A rule was broken (origin, hello, bad messages, no pong). */
  POLICY: 1008,
  /** A message too large to read. */
  TOO_LARGE: 1009,
  /** Too many connections. */
  TRY_AGAIN_LATER: 1013,
  /** The hello's token was refused. */
  TOKEN_REFUSED: 4001,
});

// ---------------------------------------------------------------- adding a puppet (HTTP)

/** The path a director POSTs a picture to. */
export const PUPPETS_PATH = '/puppets';

/** The vertex counts a new puppet's mesh may ask for, and the page's default. */
export const PUPPET_VERTICES = Object.freeze({
  MIN: 50,
  MAX: 20000,
  DEFAULT: 1000,
});

/** The largest picture the daemon takes (bytes). */
export const MAX_PICTURE_BYTES = 16777216;

// ---------------------------------------------------------------- binary frames

/** Every binary frame starts with a header of this many bytes. */
export const FRAME_HEADER_BYTES = 32;

/** A binary frame's `kind` (the header's first u32); clients skip kinds they do not know. */
export const FRAME_KIND = Object.freeze({
  VERTICES: 1,
  RIG: 2,
  HANDLES: 3,
  DEPTH: 4,
});

/** Where each field of the little-endian header starts (bytes): kind u32, puppet u32, sequence u64, input_time f64, count u32, generation u32. */
export const FRAME_HEADER = Object.freeze({
  KIND: 0,
  PUPPET: 4,
  SEQUENCE: 8,
  INPUT_TIME: 16,
  COUNT: 24,
  GENERATION: 28,
});

// ---------------------------------------------------------------- exports

/** The formats a director downloads a take as (`Format`): `name` is the export route's `format=`, the file is `extension`, served as `mime`; `label` is for people. */
export const EXPORT_FORMATS = Object.freeze([
  Object.freeze({ name: 'glb', extension: 'glb', mime: 'model/gltf-binary', label: 'glTF (.glb)' }),
  Object.freeze({ name: 'mp4', extension: 'mp4', mime: 'video/mp4', label: 'video (.mp4)' }),
  Object.freeze({ name: 'mov', extension: 'mov', mime: 'video/quicktime', label: 'ProRes 4444 with alpha (.mov)' }),
  Object.freeze({ name: 'webm', extension: 'webm', mime: 'video/webm', label: 'video with alpha (.webm)' }),
  Object.freeze({ name: 'spine', extension: 'zip', mime: 'application/zip', label: 'Spine (.zip: JSON, atlas, pictures)' }),
]);
