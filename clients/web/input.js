// Where the stage sits in the window and what pointers do on it:
// `StageView` letterboxes the stage element and its canvases and maps stage
// coordinates (y-up) to client coordinates (CSS pixels, y-down) and back;
// `PointerContacts` turns a performer's mouse, pen and touch pointers into
// one "contacts" message per animation frame, after the tools had their say.

import { CONTACT_PHASE, contactDown, contactMove, contactUp, contactsMessage } from './protocol.js';

export class StageView {
  /**
   * element: the #stage box; canvases: the canvases inside it, sized to its
   * device pixels, or to fit `fixedSize` ({width, height} device pixels, the
   * show view's `size=`) whatever the window. top(): CSS pixels at the top
   * of the window the stage must leave free (the toolbar).
   */
  constructor(element, canvases, { fixedSize = null, top = () => 0 } = {}) {
    this.element = element;
    this.canvases = canvases;
    this.fixedSize = fixedSize;
    this.top = top;
    this.size = null; // {width, height} in stage units, once a stage message came
  }

  /** Fits the stage into the window below the toolbar, centred, and sizes the canvases' drawing buffers. */
  layout() {
    const w = this.size?.width ?? 16;
    const h = this.size?.height ?? 9;
    const top = Math.min(this.top(), innerHeight - 1);
    const areaH = innerHeight - top;
    const scale = Math.min(innerWidth / w, areaH / h);
    const cssW = w * scale;
    const cssH = h * scale;
    Object.assign(this.element.style, {
      width: `${cssW}px`, height: `${cssH}px`,
      left: `${(innerWidth - cssW) / 2}px`, top: `${top + (areaH - cssH) / 2}px`,
    });
    // A fixed size draws the stage as large as fits in it, at the stage's
    // aspect (all of it when the aspects agree), scaled to the window by CSS.
    const fixed = this.fixedSize;
    const px = fixed ? Math.min(fixed.width / w, fixed.height / h) : scale * (devicePixelRatio || 1);
    for (const c of this.canvases) {
      c.width = Math.max(1, Math.round(w * px));
      c.height = Math.max(1, Math.round(h * px));
    }
  }

  /** Client coordinates of a stage point (the stage's top left corner before there is a stage). */
  stageToClient(x, y) {
    const r = this.element.getBoundingClientRect();
    if (!this.size) return [r.left, r.top];
    return [r.left + (x / this.size.width) * r.width, r.top + (1 - y / this.size.height) * r.height];
  }

  /** The stage point under client coordinates. */
  clientToStage(cx, cy) {
    const r = this.element.getBoundingClientRect();
    return [((cx - r.left) / r.width) * this.size.width, (1 - (cy - r.top) / r.height) * this.size.height];
  }
}

export class PointerContacts {
  /**
   * element: where pointers land (the stage); view: its StageView.
   * canStart(): whether a new pointer may act (a connected performer).
   * tools: tried in order before a pointer becomes a contact; each may have
   *   pointerDown(e, x, y) -> true if it took the pointer,
   *   pointerMove(e)       -> true if it took the move,
   *   pointerUp(e)         (told of every lift).
   * onLifted(contact): a contact (true), or a pointer a tool took (false),
   *   ended (a contact's dot should go at once).
   */
  constructor(element, view, { canStart, tools, onLifted }) {
    this.view = view;
    this.canStart = canStart;
    this.tools = tools;
    this.onLifted = onLifted;
    this.active = new Map(); // pointerId -> latest stage point, for contacts that went "down"
    this.toolHeld = new Set(); // pointerIds a tool took (a brush stroke, a curve being drawn)
    this.queue = [];         // contact events not yet sent, in order

    element.addEventListener('pointerdown', (e) => this.onDown(e));
    element.addEventListener('pointermove', (e) => this.onMove(e));
    element.addEventListener('pointerup', (e) => this.onLift(e));
    element.addEventListener('pointercancel', (e) => this.onLift(e));
  }

  onDown(e) {
    if (!this.canStart()) return;
    const [x, y] = this.view.clientToStage(e.clientX, e.clientY);
    for (const tool of this.tools) {
      if (tool.pointerDown?.(e, x, y)) {
        // Captured, so its lift reaches us wherever it happens.
        e.currentTarget.setPointerCapture(e.pointerId);
        this.toolHeld.add(e.pointerId);
        return;
      }
    }
    if (e.pointerType === 'mouse' && e.button !== 0) return;
    // Capture: moves and the lift still reach us when the finger leaves the stage.
    e.currentTarget.setPointerCapture(e.pointerId);
    this.active.set(e.pointerId, { x, y });
    this.queue.push(contactDown(e.pointerId, x, y));
  }

  onMove(e) {
    for (const tool of this.tools) if (tool.pointerMove?.(e)) return;
    const c = this.active.get(e.pointerId);
    if (!c) return; // hovering mouse, or a contact from before a reconnect
    [c.x, c.y] = this.view.clientToStage(e.clientX, e.clientY);
    this.queue.push(contactMove(e.pointerId, c.x, c.y));
  }

  onLift(e) {
    for (const tool of this.tools) tool.pointerUp?.(e);
    if (this.toolHeld.delete(e.pointerId)) this.onLifted(false);
    if (!this.active.delete(e.pointerId)) return;
    this.queue.push(contactUp(e.pointerId));
    this.onLifted(true);
  }

  /** Stage points of the pointers that hold contacts now. */
  points() {
    return this.active.values();
  }

  /** How many pointers hold the stage: contacts and pointers a tool took. */
  held() {
    return this.active.size + this.toolHeld.size;
  }

  /** Forgets every contact: the server forgets them with the connection. */
  reset() {
    this.active.clear();
    this.toolHeld.clear();
    this.queue = [];
  }

  /**
   * The next "contacts" message, or null when nothing waits. Each contact
   * appears at most once in it: successive moves collapse into the newest,
   * and anything after a contact's first event otherwise (a move right after
   * "down", an "up") waits for the next message, so the server never has to
   * order two events of one id.
   */
  takeMessage() {
    if (this.queue.length === 0) return null;
    const batch = new Map();
    const rest = [];
    const deferred = new Set();
    for (const ev of this.queue) {
      const prev = batch.get(ev.id);
      if (!deferred.has(ev.id) && (!prev || (prev.phase === CONTACT_PHASE.MOVE && ev.phase === CONTACT_PHASE.MOVE))) {
        batch.set(ev.id, ev);
      } else {
        deferred.add(ev.id);
        rest.push(ev);
      }
    }
    this.queue = rest;
    return contactsMessage([...batch.values()]);
  }
}
