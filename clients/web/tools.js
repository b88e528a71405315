// The performer's tools beside plain dragging, each with its controls in
// the bar: the pin tool (click to pin, click a pin to remove it), the
// stiffness and depth-layer paint brush (dabs, and saving the painted
// weights), the curve tool (draw a stroke: it becomes a curve puppet), the key pose
// slider of a skeleton puppet, undo/redo/reset per puppet, the replays'
// play/pause toggles, the takes' controls and overdub's replace tool; and
// the calibration marks `?calibrate=` asks for. Tools take pointers before
// they become contacts (see input.js). Each shows only to the roles the
// server lets use it (`setEnabled`), since roles arrive with the stage
// message and change when a refused token falls back to viewing.

import {
  EXPORT_FORMATS, HANDLE_KIND, RIG_KIND,
  addCurveMessage, depthFlipMessage, paintDepthMessage, paintMessage, pinMessage, poseMessage, redoMessage, replaceRegion, replayMessage, resetMessage,
  saveWeightsMessage, undoMessage, unpinMessage,
} from './protocol.js';
import { anchorPoint, keyHandleAnchor } from './overlay.js';

// How near (CSS pixels) a click must be to a pin to remove it.
const PIN_REACH = 12;

// The brush strengths the server takes (docs/protocol.md, `paint`).
const STRENGTH_MIN = 0.1;
const STRENGTH_MAX = 10;

// How long after the page's own change of the key pose slider the server's
// pose messages wait (they echo earlier changes): longer than a round trip.
const POSE_QUIET_MS = 400;

/**
 * Overdub's "replace": while on, a press on a puppet marks a disc of its
 * rest shape; the next overdub leaves out what the played take's hands did
 * there (the live performer re-records that part: the left arm, say).
 */
export class ReplaceTool {
  constructor(button, { puppets, onChange, radius = 40 }) {
    this.button = button;
    this.puppets = puppets;
    this.onChange = onChange;
    this.radius = radius;
    this.on = false;
    this.enabled = false;
    this.discs = []; // {puppet, at (rest), anchor (to draw it on the pose)}
    button.addEventListener('click', () => {
      this.on = !this.on;
      this.button.setAttribute('aria-pressed', String(this.on));
      if (!this.on) this.clear();
    });
  }

  /**
   * While a take records or plays there is no overdub to mark for: the
   * toggle is disabled and marking stops (the marks stay for the next).
   */
  setBusy(busy) {
    this.button.disabled = busy;
    if (busy && this.on) {
      this.on = false;
      this.button.setAttribute('aria-pressed', 'false');
    }
  }

  /** Shows the toggle (directors: overdubs are theirs). */
  setEnabled(on) {
    this.enabled = on;
    this.button.hidden = !on;
    if (!on && this.on) {
      this.on = false;
      this.button.setAttribute('aria-pressed', 'false');
      this.clear();
    }
  }

  clear() {
    this.discs = [];
    this.onChange();
  }

  pointerDown(e, x, y) {
    if (!this.on) return false;
    // The topmost puppet whose current pose covers the point.
    for (const p of [...this.puppets()].reverse()) {
      const anchor = keyHandleAnchor({ at: [x, y] }, p.positions, p.src.triangles);
      if (!anchor) continue;
      const [ax, ay] = anchorPoint(anchor, p.positions, null);
      if (Math.hypot(ax - x, ay - y) > 0.5) continue;
      const rest = anchorPoint(anchor, p.src.rest, null);
      this.discs.push({ puppet: p.id, at: rest, anchor });
      this.onChange();
      return true;
    }
    return true; // off the puppets: nothing to mark, and not a contact either
  }

  /** The discs as playMessage's `replace` (on puppets still on stage). */
  regions() {
    const shown = new Set(this.puppets().map((p) => p.id));
    return this.discs.filter((d) => shown.has(d.puppet)).map((d) => replaceRegion(d.puppet, d.at, this.radius));
  }

  /** The discs where they are now, for the overlay. */
  outlines() {
    const out = [];
    for (const d of this.discs) {
      const p = this.puppets().find((q) => q.id === d.puppet);
      if (!p) continue;
      const [x, y] = anchorPoint(d.anchor, p.positions, null);
      out.push({ x, y, radius: this.radius });
    }
    return out;
  }
}

export class PinTool {
  /**
   * button: the "pin" toggle. puppets(): the current puppet states;
   * handleAt(puppet, i): where its handle i is drawn (stage point);
   * stageToClient(x, y): client coordinates; send(message).
   */
  constructor(button, { puppets, handleAt, stageToClient, send }) {
    this.button = button;
    this.puppets = puppets;
    this.handleAt = handleAt;
    this.stageToClient = stageToClient;
    this.send = send;
    this.on = false;
    this.enabled = false;
    button.addEventListener('click', () => {
      this.on = !this.on;
      this.button.setAttribute('aria-pressed', String(this.on));
    });
  }

  /** Shows the toggle (performers and directors). */
  setEnabled(on) {
    this.enabled = on;
    this.button.hidden = !on;
    if (!on) {
      this.on = false;
      this.button.setAttribute('aria-pressed', 'false');
    }
  }

  // While the tool is on, or with Shift held, a press pins or unpins; with
  // Alt held it brings the part behind there in front (a fold).
  pointerDown(e, x, y) {
    if (this.enabled && e.altKey) {
      this.send(depthFlipMessage(x, y));
      return true;
    }
    if (!this.enabled || !(e.shiftKey || this.on)) return false;
    this.pinOrUnpin(x, y, e.clientX, e.clientY);
    return true;
  }

  // A pin within reach of the click is removed; otherwise a new one is made.
  pinOrUnpin(x, y, cx, cy) {
    let best = null;
    let bestDist = PIN_REACH;
    for (const p of this.puppets()) {
      p.handles.forEach((h, i) => {
        if (h.kind !== HANDLE_KIND.PIN) return;
        const [hx, hy] = this.stageToClient(...this.handleAt(p, i));
        const d = Math.hypot(hx - cx, hy - cy);
        if (d < bestDist) { best = { puppet: p.id, handle: h.id }; bestDist = d; }
      });
    }
    this.send(best ? unpinMessage(best.puppet, best.handle) : pinMessage(x, y));
  }
}

export class PaintTool {
  /**
   * elements: {controls, button, radius, strength, mode, layer, save} of
   * the bar (mode: "stiffness" or "depth", the depth layer to paint).
   * puppets(): the current puppet states; clientToStage(cx, cy);
   * send(message); reportError(message); onChange(): the brush moved or the
   * tool turned on or off (the overlay should redraw).
   */
  constructor(elements, { puppets, clientToStage, send, reportError, onChange }) {
    this.elements = elements;
    this.puppets = puppets;
    this.clientToStage = clientToStage;
    this.send = send;
    this.reportError = reportError;
    this.onChange = onChange;
    this.on = false;
    this.enabled = false;
    this.brush = null;          // {x, y, down} where the brush is (stage coordinates)
    this.painted = new Set();   // puppet ids painted since the last save
    this.stroke = 0;            // the current stroke's number: its dabs undo together
    this.maxRadius = Infinity;  // the stage's larger side, once a stage came
    const { button, save } = elements;
    button.addEventListener('click', () => {
      this.on = !this.on;
      button.setAttribute('aria-pressed', String(this.on));
      if (!this.on) this.brush = null;
      this.onChange();
    });
    save.addEventListener('click', () => this.saveWeights());
  }

  /** Shows the controls (directors only). */
  setEnabled(on) {
    this.enabled = on;
    this.elements.controls.hidden = !on;
    if (!on && this.on) {
      this.on = false;
      this.brush = null;
      this.elements.button.setAttribute('aria-pressed', 'false');
      this.onChange();
    }
  }

  /**
   * A stage message: the brush's radius may not exceed the stage's larger
   * side (the server refuses it beyond).
   */
  setStage(stageSize) {
    const max = Math.max(stageSize.width, stageSize.height);
    this.maxRadius = max;
    this.elements.radius.max = String(max);
    if (this.radius > max) this.elements.radius.value = String(max);
  }

  get radius() {
    return Number(this.elements.radius.value);
  }

  get strength() {
    return Number(this.elements.strength.value);
  }

  get paintsDepth() {
    return this.elements.mode?.value === 'depth';
  }

  get layer() {
    return Math.min(32767, Math.max(0, Math.round(Number(this.elements.layer?.value ?? 0))));
  }

  pointerDown(e, x, y) {
    if (!this.on) return false;
    e.currentTarget.setPointerCapture(e.pointerId);
    this.brush = { x, y, down: true };
    this.stroke++;
    this.onChange();
    return true;
  }

  // While the tool is on, every move (hovering too) moves the brush.
  pointerMove(e) {
    if (!this.on) return false;
    const [x, y] = this.clientToStage(e.clientX, e.clientY);
    this.brush = { x, y, down: this.brush?.down ?? false };
    this.onChange();
    return true;
  }

  pointerUp() {
    if (this.brush) this.brush.down = false;
  }

  // One dab per animation frame while the brush is down, on every puppet
  // whose current outline box it touches (the server paints only triangles
  // under it).
  flush() {
    const brush = this.brush;
    if (!this.on || !brush?.down) return;
    const radius = Math.min(this.radius, this.maxRadius);
    if (!(radius > 0 && this.strength > 0)) return this.reportError('paint radius and strength must be positive');
    const strength = Math.min(STRENGTH_MAX, Math.max(STRENGTH_MIN, this.strength));
    for (const p of this.puppets()) {
      const v = p.positions;
      let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
      for (let i = 0; i < v.length; i += 2) {
        x0 = Math.min(x0, v[i]); x1 = Math.max(x1, v[i]);
        y0 = Math.min(y0, v[i + 1]); y1 = Math.max(y1, v[i + 1]);
      }
      if (brush.x + radius < x0 || brush.x - radius > x1 || brush.y + radius < y0 || brush.y - radius > y1) continue;
      if (this.paintsDepth) this.send(paintDepthMessage(p.id, brush.x, brush.y, radius, this.layer, this.stroke));
      else this.send(paintMessage(p.id, brush.x, brush.y, radius, strength, this.stroke));
      this.painted.add(p.id);
    }
  }

  // The puppets painted since the last save (and still on stage), or every puppet if none was.
  saveWeights() {
    const shown = this.puppets().map((p) => p.id);
    const painted = shown.filter((id) => this.painted.has(id));
    const ids = painted.length ? painted : shown;
    for (const puppet of ids) this.send(saveWeightsMessage(puppet));
    this.painted.clear();
  }

  /** What the overlay draws of the brush: {x, y, radius, stiffens}, or null. */
  outline() {
    if (!this.on || !this.brush) return null;
    return { x: this.brush.x, y: this.brush.y, radius: this.radius, stiffens: this.strength >= 1 };
  }
}

// A drawn stroke keeps a point only this far (stage units) from the last:
// evenly enough for the server's resampling, few enough for one message.
const CURVE_STEP = 3;

/**
 * The curve tool (directors): while on, a drag draws a stroke, and letting
 * go asks the server to make it a curve puppet of the width and colour in
 * the bar (`add_curve`), which then appears on every page.
 */
export class CurveTool {
  /** elements: {button, width, colour}; clientToStage(cx, cy); send(message); onChange(): redraw the overlay. */
  constructor(elements, { clientToStage, send, reportError, onChange }) {
    this.elements = elements;
    this.clientToStage = clientToStage;
    this.send = send;
    this.reportError = reportError;
    this.onChange = onChange;
    this.on = false;
    this.points = null;   // the stroke being drawn (stage points), or null
    this.count = 0;       // curves drawn by this page, for their names
    elements.button.addEventListener('click', () => {
      this.on = !this.on;
      elements.button.setAttribute('aria-pressed', String(this.on));
      this.points = null;
      this.onChange();
    });
  }

  setEnabled(on) {
    this.elements.button.hidden = !on;
    this.elements.width.parentElement.hidden = !on;
    this.elements.colour.parentElement.hidden = !on;
    if (!on && this.on) {
      this.on = false;
      this.points = null;
      this.elements.button.setAttribute('aria-pressed', 'false');
      this.onChange();
    }
  }

  pointerDown(e, x, y) {
    if (!this.on) return false;
    e.currentTarget.setPointerCapture(e.pointerId);
    this.points = [[x, y]];
    this.onChange();
    return true;
  }

  pointerMove(e) {
    if (!this.on) return false;
    if (this.points) {
      const [x, y] = this.clientToStage(e.clientX, e.clientY);
      const [lx, ly] = this.points[this.points.length - 1];
      if (Math.hypot(x - lx, y - ly) >= CURVE_STEP) {
        this.points.push([x, y]);
        this.onChange();
      }
    }
    return true;
  }

  pointerUp() {
    const points = this.points;
    this.points = null;
    if (!this.on || !points) return;
    this.onChange();
    if (points.length < 3) return this.reportError('draw a longer stroke for a curve');
    const width = Number(this.elements.width.value);
    this.count += 1;
    this.send(addCurveMessage(`curve ${this.count}`, points, width, this.elements.colour.value));
  }

  /** The stroke being drawn, for the overlay: {points, width, colour}, or null. */
  sketch() {
    if (!this.points) return null;
    return { points: this.points, width: Number(this.elements.width.value), colour: this.elements.colour.value };
  }
}

/**
 * The key pose slider of the first skeleton puppet with key poses: shows
 * the puppet's live blend (the server's `pose` messages, so a page opened
 * later shows where the puppet is, not rest→first pose at 0) to everyone;
 * performers and directors move it.
 */
export class PoseSlider {
  /** elements: {controls, from, to, t} of the bar; send(message). */
  constructor(elements, { send }) {
    this.elements = elements;
    this.send = send;
    this.enabled = false;
    this.puppet = null;   // the puppet id it shows, or null
    this.held = false;    // the performer's pointer is on the slider
    this.quietUntil = 0;  // performance.now() until which the page's own changes are in flight
    this.pending = null;  // a pose message that came while held or quiet
    this.timer = null;
    const { from, to, t } = elements;
    t.addEventListener('input', () => this.sendPose());
    from.addEventListener('change', () => this.sendPose());
    to.addEventListener('change', () => this.sendPose());
    // While a hand is on the slider, and shortly after the page changed
    // it, the server's echoes of earlier changes would move the controls
    // back under the hand: they wait, and the newest then shows.
    t.addEventListener('pointerdown', () => { this.held = true; });
    const release = () => {
      this.held = false;
      this.applyPending();
    };
    t.addEventListener('pointerup', release);
    t.addEventListener('pointercancel', release);
  }

  applyPending() {
    clearTimeout(this.timer);
    const wait = this.quietUntil - performance.now();
    if (wait > 0) {
      this.timer = setTimeout(() => this.applyPending(), wait);
      return;
    }
    if (this.pending && !this.held) this.onPose(this.pending);
  }

  /** Lets the page move the slider (performers and directors); viewers see it. */
  setEnabled(on) {
    this.enabled = on;
    for (const e of [this.elements.from, this.elements.to, this.elements.t]) e.disabled = !on;
  }

  // Offers the key poses of the first skeleton puppet that has some.
  setup(puppets) {
    const { controls, from, to, t } = this.elements;
    const p = puppets.find((q) => q.rig.kind === RIG_KIND.SKELETON && q.rig.poses?.length);
    controls.hidden = !p;
    this.puppet = p ? p.id : null;
    this.pending = null;
    this.quietUntil = 0;
    if (!p) return;
    for (const select of [from, to]) {
      select.replaceChildren(...p.rig.poses.map((name) => new Option(name, name)));
    }
    from.selectedIndex = 0;
    to.selectedIndex = p.rig.poses.length > 1 ? 1 : 0;
    t.value = '0';
    controls.dataset.puppet = String(p.id);
  }

  /** A `pose` message: the puppet's blend now. */
  onPose(msg) {
    if (msg.puppet !== this.puppet) return;
    if (this.held || performance.now() < this.quietUntil) {
      this.pending = msg;
      this.applyPending();
      return;
    }
    this.pending = null;
    const { from, to, t } = this.elements;
    // At rest the server leaves `from` and `to` out: the selects keep
    // their poses and the slider sits at 0.
    for (const [select, name] of [[from, msg.from], [to, msg.to]]) {
      if (name !== undefined && [...select.options].some((o) => o.value === name)) select.value = name;
    }
    t.value = String(msg.from === undefined ? 0 : msg.t ?? 0);
  }

  /** What the slider shows: {puppet, from, to, t}, or null without one. */
  shown() {
    if (this.puppet === null) return null;
    const { from, to, t } = this.elements;
    return { puppet: this.puppet, from: from.value, to: to.value, t: Number(t.value) };
  }

  sendPose() {
    if (!this.enabled || this.puppet === null) return;
    this.quietUntil = performance.now() + POSE_QUIET_MS;
    const { from, to, t } = this.elements;
    this.send(poseMessage(this.puppet, from.value, to.value, Number(t.value)));
  }
}

/**
 * Undo, redo and reset per puppet, enabled by the server's `history`
 * messages (how many edits each way). Reset asks twice: the first press
 * arms it for a few seconds, the second sends it. On a stage of several
 * puppets a selector picks whose buttons show (one group, not one per
 * puppet: the toolbar must not grow a row with each puppet added).
 */
export class EditControls {
  /** container: where the per-puppet groups go; send(message). */
  constructor(container, { send }) {
    this.container = container;
    this.send = send;
    this.enabled = false;
    this.groups = new Map(); // puppet id -> {undo, redo, reset, history, group}
    this.selected = null;    // the puppet whose buttons show
    this.picker = document.createElement('select');
    this.picker.id = 'edit-puppet';
    this.picker.title = 'The puppet undo, redo and reset act on';
    this.picker.addEventListener('change', () => this.select(Number(this.picker.value)));
  }

  /** Shows puppet `id`'s buttons (the others' stay, hidden). */
  select(id) {
    this.selected = this.groups.has(id) ? id : (this.groups.keys().next().value ?? null);
    for (const [pid, g] of this.groups) g.group.hidden = pid !== this.selected;
    if (this.selected !== null) this.picker.value = String(this.selected);
  }

  setEnabled(on) {
    this.enabled = on;
    this.container.hidden = !on || this.groups.size === 0;
  }

  /** A stage message: one group per puppet, disabled until its history comes. */
  setup(puppets) {
    this.groups.clear();
    const named = puppets.length > 1;
    // Top first, as the puppets panel lists them.
    this.picker.replaceChildren(...[...puppets].reverse().map((p) => new Option(`${p.id}: ${p.src.name}`, String(p.id))));
    this.picker.hidden = !named;
    this.container.replaceChildren(this.picker, ...puppets.map((p) => {
      const group = document.createElement('span');
      group.className = 'edit-group';
      group.dataset.puppet = String(p.id);
      const label = document.createElement('span');
      label.className = 'edit-name';
      label.textContent = p.src.name;
      label.hidden = true; // the selector names it
      const button = (cls, text, title, onClick) => {
        const b = document.createElement('button');
        b.type = 'button';
        b.className = cls;
        b.textContent = text;
        b.title = title;
        b.disabled = true;
        b.addEventListener('click', onClick);
        return b;
      };
      const g = { history: null, armed: null, group };
      g.undo = button('undo', '↶ undo', `Undo the last edit of ${p.src.name} (a paint stroke, a pin, a pose)`,
        () => this.send(undoMessage(p.id)));
      g.redo = button('redo', '↷ redo', `Redo the last undone edit of ${p.src.name}`, () => this.send(redoMessage(p.id)));
      g.reset = button('reset', '⟲ reset', `Back to ${p.src.name} as loaded (press twice)`, () => this.pressReset(p.id, g));
      group.append(label, g.undo, g.redo, g.reset);
      this.groups.set(p.id, g);
      return group;
    }));
    this.select(this.selected);
    this.setEnabled(this.enabled);
  }

  pressReset(puppet, g) {
    if (g.armed) {
      clearTimeout(g.armed);
      g.armed = null;
      g.reset.textContent = '⟲ reset';
      g.reset.classList.remove('armed');
      this.send(resetMessage(puppet));
      return;
    }
    g.reset.textContent = '⟲ reset?';
    g.reset.classList.add('armed');
    g.armed = setTimeout(() => {
      g.armed = null;
      g.reset.textContent = '⟲ reset';
      g.reset.classList.remove('armed');
    }, 3000);
  }

  /** A `history` message. */
  onHistory(msg) {
    const g = this.groups.get(msg.puppet);
    if (!g) return;
    g.history = msg;
    g.undo.disabled = !(msg.undo > 0);
    g.redo.disabled = !(msg.redo > 0);
    g.reset.disabled = false;
    g.undo.title = g.undo.title.replace(/ \(\d+\)$/, '') + (msg.undo > 0 ? ` (${msg.undo})` : '');
    g.redo.title = g.redo.title.replace(/ \(\d+\)$/, '') + (msg.redo > 0 ? ` (${msg.redo})` : '');
  }
}

/**
 * Play/pause toggles of the stage's replay inputs (the server's `inputs`
 * message), for directors: a rig stage's demo replay would otherwise fight
 * the performer.
 */
export class ReplayControls {
  constructor(container, { send }) {
    this.container = container;
    this.send = send;
    this.enabled = false;
    this.replays = [];
  }

  setEnabled(on) {
    this.enabled = on;
    this.render();
  }

  /** An `inputs` message. */
  onInputs(msg) {
    this.replays = Array.isArray(msg.replays) ? msg.replays : [];
    this.render();
  }

  render() {
    this.container.hidden = !this.enabled || this.replays.length === 0;
    this.container.replaceChildren(...this.replays.map((r) => {
      const b = document.createElement('button');
      b.type = 'button';
      b.className = 'replay';
      b.dataset.source = r.name;
      b.setAttribute('aria-pressed', String(!!r.playing));
      b.textContent = `${r.name}: ${r.playing ? 'playing' : 'paused'}`;
      b.title = r.playing ? `The replay ${r.name} plays: press to pause it` : `The replay ${r.name} is paused: press to play it`;
      b.addEventListener('click', () => this.send(replayMessage(r.name, !r.playing)));
      return b;
    }));
  }
}

// `?calibrate=0.1` shows the four marks `puppetry calibrate` expects, that
// fraction of the stage in from its edges, numbered in the order to touch.
// The inset, or null when the page was not asked for marks.
export function calibrationInset(params) {
  return params.has('calibrate') ? Number(params.get('calibrate') || 0.1) : null;
}

/** The marks' stage points, in the order to touch them (top left first, clockwise). */
export function calibrationMarks(inset, stageSize) {
  const { width: w, height: h } = stageSize;
  const lo = inset, hi = 1 - inset;
  return [[lo * w, hi * h], [hi * w, hi * h], [hi * w, lo * h], [lo * w, lo * h]];
}

/**
 * Takes: the record button (red with the elapsed time on every page while
 * a take records), the take list, play, overdub and the download. Everyone
 * sees the state; directors get the buttons. One button starts a take and, while anything
 * runs (a take recording, one playing, an overdub), reads "■ stop" and
 * stops all of it: there is no second stop to press by mistake. Play,
 * overdub and replace are disabled while anything runs, and the take
 * being recorded is in the list but cannot be chosen.
 */
export class TakeControls {
  constructor(elements, { send, messages, token }) {
    this.el = elements;
    this.send = send;
    this.m = messages;
    this.token = token; // () => the director's token, sent with downloads
    this.state = { recording: null, playing: null, error: null };
    this.since = 0; // performance.now() when `elapsed` was 0
    for (const b of this.buttons()) b.hidden = true;
    this.el.controls.hidden = true;
    this.exporting = null; // the newest `export` message while one runs
    // The daemon's downloadable formats, after the take itself.
    for (const f of EXPORT_FORMATS) {
      const option = document.createElement('option');
      option.value = f.name;
      option.textContent = f.label;
      this.el.format.append(option);
    }
    setInterval(() => this.showElapsed(), 250);
    this.listen();
  }

  buttons() {
    const e = this.el;
    return [e.record, e.play, e.overdub, e.list, e.format, e.download];
  }

  /** Which buttons show: directors record, play and download (the daemon serves takes to a director's token only). */
  setRole({ direct }) {
    const e = this.el;
    for (const b of this.buttons()) b.hidden = !direct;
    this.fit();
  }

  // The box shows only with buttons in it (a viewer has none; the take
  // state hangs under the bar on its own, shown while it says something).
  fit() {
    const e = this.el;
    e.controls.hidden = this.buttons().every((b) => b.hidden);
  }

  listen() {
    this.el.download.addEventListener('click', () => this.download());
    this.el.record.addEventListener('click', () => {
      const { recording, playing } = this.state;
      if (!recording && !playing) {
        this.send(this.m.record());
        return;
      }
      // The recording first: an overdub then ends with both its takes' hands let go.
      if (recording) this.send(this.m.stopRecording());
      if (playing) this.send(this.m.stopPlaying());
    });
    this.el.play.addEventListener('click', () => this.chosen() && this.send(this.m.play(this.chosen(), false)));
    this.el.overdub.addEventListener('click', () => {
      if (!this.chosen()) return;
      const replace = this.replaceTool?.regions() ?? [];
      this.send(this.m.play(this.chosen(), true, { replace }));
      this.replaceTool?.clear();
    });
    this.el.list.addEventListener('change', () => this.refresh());
  }

  /** The chosen take, unless something runs (nothing can be played then). */
  chosen() {
    if (this.running()) return null;
    const o = this.el.list.selectedOptions[0];
    return o && !o.disabled ? o.value : null;
  }

  running() {
    return !!(this.state.recording || this.state.playing);
  }

  /** The buttons as the state allows: one stop while anything runs, play and overdub only when they would play. */
  refresh() {
    const e = this.el;
    const running = this.running();
    e.record.setAttribute('aria-pressed', String(!!this.state.recording));
    e.record.textContent = running ? '■ stop' : '● rec';
    e.record.title = running
      ? `Stop ${[this.state.recording && `recording ${this.state.recording}`, this.state.playing && `playing ${this.state.playing}`].filter(Boolean).join(' and ')}`
      : 'Record a take of everything on stage (every page shows it)';
    e.play.disabled = e.overdub.disabled = !this.chosen();
    this.replaceTool?.setBusy(running);
  }

  /**
   * Downloads the chosen take as the file itself or an export the daemon
   * makes. The daemon wants the director's token as a header (a plain link
   * cannot carry one, which is the point: a link on any page cannot fetch
   * a take), so the file is fetched, then saved from memory under its name.
   */
  async download() {
    const take = this.chosen();
    if (!take) return;
    const format = this.el.format.value;
    const name = encodeURIComponent(take);
    const path = format === 'take' ? `/takes/${name}.take` : `/takes/${name}/export?format=${format}&fps=30`;
    const failed = (why) => {
      this.state.error = `download of ${take}: ${why}`;
      this.showElapsed();
    };
    let blob;
    const extension = EXPORT_FORMATS.find((f) => f.name === format)?.extension ?? 'take';
    let file = `${take}.${extension}`;
    try {
      const answer = await fetch(path, { headers: { Authorization: `Bearer ${this.token()}` }, cache: 'no-store' });
      if (!answer.ok) {
        failed((await answer.text()).trim() || `HTTP ${answer.status}`);
        return;
      }
      file = /filename="([^"]+)"/.exec(answer.headers.get('Content-Disposition') ?? '')?.[1] ?? file;
      blob = await answer.blob();
    } catch (err) {
      failed(err.message);
      return;
    }
    const url = URL.createObjectURL(blob);
    const link = document.createElement('a');
    link.href = url;
    link.download = file;
    document.body.append(link);
    link.click();
    link.remove();
    // The browser has the file once the click is handled; give it time.
    setTimeout(() => URL.revokeObjectURL(url), 60_000);
  }

  /** An `export` message: progress of an export being downloaded. */
  onExport(msg) {
    this.exporting = msg.finished ? null : msg;
    if (msg.finished && msg.error) this.state.error = `export of ${msg.take}: ${msg.error}`;
    this.showElapsed();
  }

  /** A `take` message. */
  onState(msg) {
    const wasRecording = this.state.recording;
    this.state = { recording: msg.recording ?? null, playing: msg.playing ?? null, error: msg.error ?? null };
    this.since = performance.now() - (msg.elapsed ?? 0) * 1000;
    this.markRecording();
    this.refresh();
    this.showElapsed();
    // A take just ended: it belongs in the list.
    if (wasRecording !== this.state.recording) this.send(this.m.listTakes());
  }

  showElapsed() {
    const s = this.state;
    let text = '';
    if (s.recording) {
      const t = (performance.now() - this.since) / 1000;
      const minutes = Math.floor(t / 60);
      text = `REC ${s.recording} ${minutes}:${(t % 60).toFixed(1).padStart(4, '0')}`;
    }
    if (s.playing) text += `${text ? ' · ' : ''}playing ${s.playing}`;
    const x = this.exporting;
    if (x) {
      const percent = x.total ? Math.floor((100 * x.done) / x.total) : 0;
      text += `${text ? ' · ' : ''}exporting ${x.take} (${x.format}) ${percent}%`;
    }
    if (!text && s.error) text = s.error;
    if (this.el.state.textContent !== text) {
      this.el.state.textContent = text;
      this.fit();
    }
    this.el.state.classList.toggle('recording', !!s.recording);
    this.el.state.classList.toggle('error', !s.recording && !!s.error);
  }

  /** A `takes` message: the list, the newest that can be played selected. */
  onList(msg) {
    const list = this.el.list;
    list.replaceChildren(...msg.takes.map((t) => {
      const o = document.createElement('option');
      o.value = t.name;
      o.dataset.label = `${t.name} (${t.duration.toFixed(1)} s${t.layers?.length ? `, over ${t.layers.join(', ')}` : ''})`;
      o.dataset.ending = t.ending ?? '';
      return o;
    }));
    this.markRecording();
    const playable = [...list.options].filter((o) => !o.disabled);
    if (playable.length) list.value = playable[playable.length - 1].value;
    this.refresh();
  }

  // The take being recorded grows as it is written: listed, but not to be chosen.
  markRecording() {
    for (const o of this.el.list.options) {
      const recording = o.value === this.state.recording || o.dataset.ending === 'recording';
      o.disabled = recording;
      o.textContent = recording ? `${o.value} (recording…)` : (o.dataset.label ?? o.value);
    }
  }
}
