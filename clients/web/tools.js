// The performer's tools beside plain dragging, each with its controls in
// the bar: the pin tool (click to pin, click a pin to remove it), the
// stiffness paint brush (dabs, and saving the painted weights), the key pose
// slider of a skeleton puppet, the takes' controls and overdub's replace
// tool; and the calibration marks `?calibrate=` asks for. Tools take pointers before they become contacts (see input.js).

import {
  HANDLE_KIND, RIG_KIND,
  paintMessage, pinMessage, poseMessage, replaceRegion, saveWeightsMessage, unpinMessage,
} from './protocol.js';
import { anchorPoint, keyHandleAnchor } from './overlay.js';

// How near (CSS pixels) a click must be to a pin to remove it.
const PIN_REACH = 12;

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
    this.discs = []; // {puppet, at (rest), anchor (to draw it on the pose)}
  }

  enable() {
    this.button.hidden = false;
    this.button.addEventListener('click', () => {
      this.on = !this.on;
      this.button.setAttribute('aria-pressed', String(this.on));
      if (!this.on) this.clear();
    });
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

  /** The discs as playMessage's `replace`. */
  regions() {
    return this.discs.map((d) => replaceRegion(d.puppet, d.at, this.radius));
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
   * stageToClient(x, y): client coordinates; send(message).
   */
  constructor(button, { puppets, stageToClient, send }) {
    this.button = button;
    this.puppets = puppets;
    this.stageToClient = stageToClient;
    this.send = send;
    this.on = false;
  }

  /** Shows the toggle (performers only). */
  enable() {
    this.button.hidden = false;
    this.button.addEventListener('click', () => {
      this.on = !this.on;
      this.button.setAttribute('aria-pressed', String(this.on));
    });
  }

  // While the tool is on, or with Shift held, a press pins or unpins.
  pointerDown(e, x, y) {
    if (!(e.shiftKey || this.on)) return false;
    this.pinOrUnpin(x, y, e.clientX, e.clientY);
    return true;
  }

  // A pin within reach of the click is removed; otherwise a new one is made.
  pinOrUnpin(x, y, cx, cy) {
    let best = null;
    let bestDist = PIN_REACH;
    for (const p of this.puppets()) {
      for (const h of p.handles) {
        if (h.kind !== HANDLE_KIND.PIN) continue;
        const [hx, hy] = this.stageToClient(h.at[0], h.at[1]);
        const d = Math.hypot(hx - cx, hy - cy);
        if (d < bestDist) { best = { puppet: p.id, handle: h.id }; bestDist = d; }
      }
    }
    this.send(best ? unpinMessage(best.puppet, best.handle) : pinMessage(x, y));
  }
}

export class PaintTool {
  /**
   * elements: {controls, button, radius, strength, save} of the bar.
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
    this.brush = null;          // {x, y, down} where the brush is (stage coordinates)
    this.painted = new Set();   // puppet ids painted since the last save
  }

  /** Shows the controls (performers only). */
  enable() {
    const { controls, button, save } = this.elements;
    controls.hidden = false;
    button.addEventListener('click', () => {
      this.on = !this.on;
      button.setAttribute('aria-pressed', String(this.on));
      if (!this.on) this.brush = null;
      this.onChange();
    });
    save.addEventListener('click', () => this.saveWeights());
  }

  get radius() {
    return Number(this.elements.radius.value);
  }

  get strength() {
    return Number(this.elements.strength.value);
  }

  pointerDown(e, x, y) {
    if (!this.on) return false;
    e.currentTarget.setPointerCapture(e.pointerId);
    this.brush = { x, y, down: true };
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
    const radius = this.radius;
    const strength = this.strength;
    if (!(radius > 0 && strength > 0)) return this.reportError('paint radius and strength must be positive');
    for (const p of this.puppets()) {
      const v = p.positions;
      let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
      for (let i = 0; i < v.length; i += 2) {
        x0 = Math.min(x0, v[i]); x1 = Math.max(x1, v[i]);
        y0 = Math.min(y0, v[i + 1]); y1 = Math.max(y1, v[i + 1]);
      }
      if (brush.x + radius < x0 || brush.x - radius > x1 || brush.y + radius < y0 || brush.y - radius > y1) continue;
      this.send(paintMessage(p.id, brush.x, brush.y, radius, strength));
      this.painted.add(p.id);
    }
  }

  // The puppets painted since the last save, or every puppet if none was.
  saveWeights() {
    const ids = this.painted.size ? [...this.painted] : this.puppets().map((p) => p.id);
    for (const puppet of ids) this.send(saveWeightsMessage(puppet));
    this.painted.clear();
  }

  /** What the overlay draws of the brush: {x, y, radius, stiffens}, or null. */
  outline() {
    if (!this.on || !this.brush) return null;
    return { x: this.brush.x, y: this.brush.y, radius: this.radius, stiffens: this.strength >= 1 };
  }
}

export class PoseSlider {
  /** elements: {controls, from, to, t} of the bar; send(message). */
  constructor(elements, { send }) {
    this.elements = elements;
    this.send = send;
    this.enabled = false;
  }

  /** Listens to the controls (performers only); they show once a stage has key poses. */
  enable() {
    const { from, to, t } = this.elements;
    this.enabled = true;
    t.addEventListener('input', () => this.sendPose());
    from.addEventListener('change', () => this.sendPose());
    to.addEventListener('change', () => this.sendPose());
  }

  // Offers the key poses of the first skeleton puppet that has some.
  setup(puppets) {
    const { controls, from, to } = this.elements;
    const p = puppets.find((q) => q.rig.kind === RIG_KIND.SKELETON && q.rig.poses?.length);
    controls.hidden = !this.enabled || !p;
    if (!p) return;
    for (const select of [from, to]) {
      select.replaceChildren(...p.rig.poses.map((name) => new Option(name, name)));
    }
    if (p.rig.poses.length > 1) to.selectedIndex = 1;
    controls.dataset.puppet = String(p.id);
  }

  sendPose() {
    const { controls, from, to, t } = this.elements;
    this.send(poseMessage(Number(controls.dataset.puppet), from.value, to.value, Number(t.value)));
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
 * a take records), the take list, play and overdub. Everyone sees the
 * state; performers get the buttons.
 */
export class TakeControls {
  constructor(elements, { send, messages }) {
    this.el = elements;
    this.send = send;
    this.m = messages;
    this.state = { recording: null, playing: null, error: null };
    this.since = 0; // performance.now() when `elapsed` was 0
    this.el.controls.hidden = false;
    for (const b of this.buttons()) b.hidden = true;
    this.exporting = null; // the newest `export` message while one runs
    setInterval(() => this.showElapsed(), 250);
  }

  buttons() {
    const e = this.el;
    return [e.record, e.play, e.overdub, e.stop, e.list, e.format, e.download];
  }

  /** Performers get the buttons. */
  enable() {
    for (const b of this.buttons()) b.hidden = false;
    this.el.download.addEventListener('click', () => this.download());
    this.el.record.addEventListener('click', () => {
      this.send(this.state.recording ? this.m.stopRecording() : this.m.record());
    });
    this.el.play.addEventListener('click', () => this.chosen() && this.send(this.m.play(this.chosen(), false)));
    this.el.overdub.addEventListener('click', () => {
      if (!this.chosen()) return;
      const replace = this.replaceTool?.regions() ?? [];
      this.send(this.m.play(this.chosen(), true, { replace }));
      this.replaceTool?.clear();
    });
    this.el.stop.addEventListener('click', () => this.send(this.m.stopPlaying()));
  }

  chosen() {
    return this.el.list.value || null;
  }

  /** Downloads the chosen take as the file itself or an export the daemon makes. */
  download() {
    const take = this.chosen();
    if (!take) return;
    const format = this.el.format.value;
    const name = encodeURIComponent(take);
    const link = document.createElement('a');
    link.href = format === 'take' ? `/takes/${name}.take` : `/takes/${name}/export?format=${format}&fps=30`;
    link.download = '';
    document.body.append(link);
    link.click();
    link.remove();
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
    this.el.record.setAttribute('aria-pressed', String(!!this.state.recording));
    this.el.record.textContent = this.state.recording ? '■ stop' : '● rec';
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
    this.el.state.textContent = text;
    this.el.state.classList.toggle('recording', !!s.recording);
    this.el.state.classList.toggle('error', !s.recording && !!s.error);
  }

  /** A `takes` message: the list, newest selected. */
  onList(msg) {
    const list = this.el.list;
    list.replaceChildren(...msg.takes.map((t) => {
      const o = document.createElement('option');
      o.value = t.name;
      o.textContent = `${t.name} (${t.duration.toFixed(1)} s${t.layers?.length ? `, over ${t.layers.join(', ')}` : ''})`;
      return o;
    }));
    if (msg.takes.length) list.value = msg.takes[msg.takes.length - 1].name;
  }
}
