// The keyframing pad (docs/protocol.md "Spatial keyframing"): a small square
// panel where a puppet's key poses sit as dots and one cursor blends them.
// Performers drag the cursor (the puppet follows live) and let it go;
// directors also add keys where it is, move keys with Shift-drag, delete
// them with a right-click or Alt-click and save them. Viewers see the dots
// and the cursor of a puppet that has keys, read-only. What is drawn is
// always the server's state (its `keys` messages), so every page shows the
// same pad. The panel shows where there is something on it (keys, or a
// stage `[[pad]]` area driving the puppet); a director on a stage with
// neither opens it from the toolbar's "keys" button to make the first.

import {
  PAD_CENTRE, PAD_MAX, PAD_MIN,
  cursorMessage, keyAddMessage, keyDeleteMessage, keyMoveMessage, saveKeysMessage,
} from './protocol.js';

// How near (CSS pixels) a press must be to a key dot to take that key.
const DOT_REACH = 10;
const DOT_RADIUS = 6;
// Key dots and the overlay's key handles share a colour, so the two read as one thing.
export const KEY_COLOUR = '#ffab00';
const CURSOR_COLOUR = '#00e5ff';

const clampPad = (v) => Math.min(PAD_MAX, Math.max(PAD_MIN, v));

export class KeyPad {
  /**
   * elements: {panel, canvas, puppet (a select), add, save, letGo, open
   * (the toolbar's button that shows an empty pad to a director)}.
   * send(message); canSend(): whether a message can go now (connected).
   */
  constructor(elements, { send, canSend }) {
    this.el = elements;
    this.send = send;
    this.canSend = canSend;
    this.editable = false;      // the cursor can be moved (performers, directors)
    this.editsKeys = false;     // keys can be added, moved, deleted and saved (directors)
    this.puppets = [];          // [{id, name}] from the stage message, in stage order
    this.selected = null;       // puppet id the pad shows
    this.state = new Map();     // puppet id -> {keys: [{name, at}], cursor?}: the newest keys message
    this.drag = null;           // {pointerId, puppet, mode: 'cursor' | 'move', key, at}
    this.pendingCursor = null;  // {puppet, at}: the newest cursor point not yet sent
    this.dirty = true;          // redraw at the next flush
    this.opened = false;        // a director asked for the pad with nothing on it yet
    this.el.panel.hidden = true;
    this.el.open?.addEventListener('click', () => {
      this.opened = !this.opened;
      this.refresh();
    });
    this.el.puppet.addEventListener('change', () => {
      this.selected = Number(this.el.puppet.value);
      this.drag = null;
      this.dirty = true;
    });
    const { canvas, add, save, letGo } = this.el;
    canvas.addEventListener('pointerdown', (e) => this.editable && this.onDown(e));
    canvas.addEventListener('pointermove', (e) => this.onMove(e));
    canvas.addEventListener('pointerup', (e) => this.onUp(e, true));
    canvas.addEventListener('pointercancel', (e) => this.onUp(e, false));
    // A right-click (or a long press on a touch screen) deletes the key
    // under it; the browser's own menu never shows over the pad.
    canvas.addEventListener('contextmenu', (e) => {
      if (!this.editable) return;
      e.preventDefault();
      if (!this.editsKeys) return;
      const key = this.keyAt(e.clientX, e.clientY);
      if (key !== null) this.send(keyDeleteMessage(this.selected, key));
    });
    add.addEventListener('click', () => this.addKey());
    save.addEventListener('click', () => this.selected !== null && this.send(saveKeysMessage(this.selected)));
    letGo.addEventListener('click', () => this.letGo());
    // K adds a key too: a mouse performer's one pointer is busy holding the
    // puppet in the pose to key, so the button is out of its reach then.
    addEventListener('keydown', (e) => {
      if (!this.editsKeys) return;
      if (e.repeat || e.ctrlKey || e.metaKey || e.altKey || (e.key !== 'k' && e.key !== 'K')) return;
      if (e.target instanceof HTMLElement && e.target.matches('input, select, textarea')) return;
      this.addKey();
    });
  }

  /**
   * What the page may do on the pad: `perform` moves the cursor and lets
   * it go, `direct` also adds, moves, deletes and saves keys.
   */
  setMode({ perform, direct }) {
    this.editable = perform;
    this.editsKeys = direct;
    const { canvas, add, save, letGo } = this.el;
    letGo.hidden = !perform;
    add.hidden = save.hidden = !direct;
    canvas.classList.toggle('editable', perform);
    if (!perform) {
      this.drag = null;
      this.pendingCursor = null;
    }
    this.refresh();
  }

  /**
   * A stage message: the puppets the pad can show (keys come in their own
   * messages). On a new connection its keys messages follow; a new lineup
   * on the same one (`sameConnection`) keeps the keys of the puppets that
   * stay, which are not sent again.
   */
  setup(puppets, { sameConnection = false } = {}) {
    this.puppets = puppets.map((p) => ({ id: p.id, name: p.src.name, pads: p.src.pads?.length ?? 0 }));
    const stays = (id) => sameConnection && this.puppets.some((p) => p.id === id);
    for (const id of [...this.state.keys()]) if (!stays(id)) this.state.delete(id);
    if (!stays(this.drag?.puppet)) this.drag = null;
    if (!stays(this.pendingCursor?.puppet)) this.pendingCursor = null;
    if (!this.puppets.some((p) => p.id === this.selected)) this.selected = this.puppets[0]?.id ?? null;
    this.refresh();
  }

  /** A `keys` message. */
  onKeys(msg) {
    this.state.set(msg.puppet, { keys: msg.keys, cursor: msg.cursor ?? null });
    // A key being moved that went away (deleted from another page) ends the move.
    if (this.drag?.mode === 'move' && this.drag.puppet === msg.puppet && this.drag.key >= msg.keys.length) this.drag = null;
    this.refresh();
  }

  // Which puppets the selector offers (all to directors, who make keys;
  // others only those with keys), whether
  // the panel shows, and the selection kept valid.
  refresh() {
    const { panel, puppet } = this.el;
    const offered = this.editsKeys ? this.puppets : this.puppets.filter((p) => this.state.get(p.id)?.keys.length);
    if (offered.length && !offered.some((p) => p.id === this.selected)) this.selected = offered[0].id;
    const ids = offered.map((p) => String(p.id)).join();
    if (puppet.dataset.ids !== ids) {
      puppet.replaceChildren(...offered.map((p) => new Option(`${p.id}: ${p.name}`, String(p.id))));
      puppet.dataset.ids = ids;
    }
    if (this.selected !== null) puppet.value = String(this.selected);
    puppet.hidden = offered.length < 2;
    // An empty pad over the stage's corner is in the way and says nothing:
    // it shows once a puppet has keys or a pad area, or when asked for.
    const used = offered.some((p) => p.pads > 0 || this.state.get(p.id)?.keys.length);
    panel.hidden = offered.length === 0 || !(used || this.opened);
    if (this.el.open) {
      this.el.open.hidden = !this.editsKeys || offered.length === 0 || used;
      this.el.open.setAttribute('aria-pressed', String(this.opened));
    }
    this.dirty = true;
  }

  // ---------------------------------------------------------------- pointers

  /** The pad point [u, v] under client coordinates, clamped to the pad. */
  padPoint(cx, cy) {
    const r = this.el.canvas.getBoundingClientRect();
    return [clampPad((cx - r.left) / r.width), clampPad(1 - (cy - r.top) / r.height)];
  }

  /** Client coordinates of a pad point. */
  padToClient([u, v]) {
    const r = this.el.canvas.getBoundingClientRect();
    return [r.left + u * r.width, r.top + (1 - v) * r.height];
  }

  /** The index of the selected puppet's key nearest to client coordinates, within reach, or null. */
  keyAt(cx, cy) {
    const keys = this.state.get(this.selected)?.keys ?? [];
    let best = null;
    let bestDist = DOT_REACH;
    keys.forEach((k, i) => {
      const [x, y] = this.padToClient(k.at);
      const d = Math.hypot(x - cx, y - cy);
      if (d < bestDist) { best = i; bestDist = d; }
    });
    return best;
  }

  onDown(e) {
    if (this.selected === null || this.drag) return;
    if (e.pointerType === 'mouse' && e.button !== 0) return; // right-click: see contextmenu
    const key = this.keyAt(e.clientX, e.clientY);
    if (key !== null && e.altKey && this.editsKeys) {
      e.preventDefault();
      this.send(keyDeleteMessage(this.selected, key));
      return;
    }
    // Capture: the drag goes on when the pointer leaves the small pad.
    this.el.canvas.setPointerCapture(e.pointerId);
    const puppet = this.selected;
    if (key !== null && e.shiftKey && this.editsKeys) {
      this.drag = { pointerId: e.pointerId, puppet, mode: 'move', key, at: this.state.get(puppet).keys[key].at };
    } else {
      this.drag = { pointerId: e.pointerId, puppet, mode: 'cursor' };
      // A press on a key recalls exactly its pose: the cursor snaps to it.
      const at = key !== null ? this.state.get(puppet).keys[key].at : this.padPoint(e.clientX, e.clientY);
      this.pendingCursor = { puppet, at };
    }
    this.dirty = true;
  }

  onMove(e) {
    const d = this.drag;
    if (!d || d.pointerId !== e.pointerId) return;
    const at = this.padPoint(e.clientX, e.clientY);
    if (d.mode === 'move') {
      d.at = at;
      this.dirty = true;
    } else {
      this.pendingCursor = { puppet: d.puppet, at };
    }
  }

  // The end of a drag: a moved key goes to where it was dropped (one
  // key_move, not one per pointer move: every move re-solves the blend); a
  // cancelled move leaves it where it was. The cursor stays where it is.
  onUp(e, dropped) {
    const d = this.drag;
    if (!d || d.pointerId !== e.pointerId) return;
    this.drag = null;
    if (d.mode === 'move' && dropped) {
      const key = this.state.get(d.puppet)?.keys[d.key];
      if (key && (key.at[0] !== d.at[0] || key.at[1] !== d.at[1])) this.send(keyMoveMessage(d.puppet, d.key, d.at));
    }
    this.dirty = true;
  }

  // ---------------------------------------------------------------- buttons

  // A key of the puppet as it is now, where the cursor is (the point being
  // dragged to, if that has not gone out yet), else at the pad's centre.
  addKey() {
    const puppet = this.selected;
    if (puppet === null) return;
    const state = this.state.get(puppet);
    const pending = this.pendingCursor?.puppet === puppet ? this.pendingCursor.at : null;
    const at = pending ?? state?.cursor ?? PAD_CENTRE;
    this.send(keyAddMessage(puppet, [...at], nextKeyName(state?.keys ?? [])));
  }

  letGo() {
    const puppet = this.selected;
    if (puppet === null) return;
    if (this.drag?.mode === 'cursor') this.drag = null;
    if (this.pendingCursor?.puppet === puppet) this.pendingCursor = null;
    this.send(cursorMessage(puppet));
  }

  // ---------------------------------------------------------------- per animation frame

  /**
   * Called once per animation frame: sends the newest cursor point (at most
   * one cursor message per frame however fast the pointer moves) and
   * redraws if anything changed.
   */
  flush() {
    if (this.pendingCursor && this.canSend()) {
      const { puppet, at } = this.pendingCursor;
      this.pendingCursor = null;
      this.send(cursorMessage(puppet, at));
    }
    if (this.dirty && !this.el.panel.hidden) {
      this.dirty = false;
      this.draw();
    }
  }

  draw() {
    const canvas = this.el.canvas;
    const css = canvas.clientWidth;
    const dpr = devicePixelRatio || 1;
    const size = Math.max(1, Math.round(css * dpr));
    if (canvas.width !== size || canvas.height !== size) canvas.width = canvas.height = size;
    const ctx = canvas.getContext('2d');
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, css, css);
    const toPad = ([u, v]) => [u * css, (1 - v) * css];

    // Quarter lines, so a performer can aim for the same spot again.
    ctx.strokeStyle = 'rgb(255 255 255 / 0.12)';
    ctx.lineWidth = 1;
    ctx.beginPath();
    for (const f of [0.25, 0.5, 0.75]) {
      ctx.moveTo(f * css, 0); ctx.lineTo(f * css, css);
      ctx.moveTo(0, f * css); ctx.lineTo(css, f * css);
    }
    ctx.stroke();

    const state = this.state.get(this.selected);
    if (!state) return;
    ctx.font = '11px system-ui, sans-serif';
    ctx.textBaseline = 'middle';
    state.keys.forEach((k, i) => {
      const moving = this.drag?.mode === 'move' && this.drag.puppet === this.selected && this.drag.key === i;
      const [x, y] = toPad(moving ? this.drag.at : k.at);
      ctx.beginPath();
      ctx.arc(x, y, DOT_RADIUS, 0, 2 * Math.PI);
      ctx.fillStyle = KEY_COLOUR;
      ctx.globalAlpha = moving ? 0.6 : 1;
      ctx.fill();
      ctx.globalAlpha = 1;
      ctx.lineWidth = 1.5;
      ctx.strokeStyle = '#000';
      ctx.stroke();
    });
    // Names beside their dots, placed so none overlaps another or a dot.
    const dots = state.keys.map((k, i) => toPad(this.drag?.mode === 'move' && this.drag.puppet === this.selected
      && this.drag.key === i ? this.drag.at : k.at));
    this.labels = keyLabelLayout(dots, state.keys.map((k) => k.name), css, (t) => ctx.measureText(t).width);
    ctx.textAlign = 'left';
    ctx.fillStyle = '#eee';
    for (const l of this.labels) ctx.fillText(l.text, l.x, l.y + LABEL_HEIGHT / 2, l.w);

    if (state.cursor) {
      const [x, y] = toPad(state.cursor);
      ctx.strokeStyle = CURSOR_COLOUR;
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.arc(x, y, 8, 0, 2 * Math.PI);
      ctx.moveTo(x - 13, y); ctx.lineTo(x - 4, y);
      ctx.moveTo(x + 4, y); ctx.lineTo(x + 13, y);
      ctx.moveTo(x, y - 13); ctx.lineTo(x, y - 4);
      ctx.moveTo(x, y + 4); ctx.lineTo(x, y + 13);
      ctx.stroke();
    }
  }
}

const LABEL_HEIGHT = 13;
const LABEL_GAP = 3;

const overlapArea = (a, b) => Math.max(0, Math.min(a.x + a.w, b.x + b.w) - Math.max(a.x, b.x))
  * Math.max(0, Math.min(a.y + a.h, b.y + b.h) - Math.max(a.y, b.y));

/**
 * Where each key's name goes on a pad `size` CSS px square: dots are the
 * keys' pad pixels, measure(text) a text's width. Each name tries right of
 * its dot, left, above, below (inside the pad), and takes the first place
 * that overlaps no name placed before and no dot; failing that the place
 * overlapping least, shortened with "…" to what fits. Returns
 * [{text, x, y, w, h}]: the box (top left) each name is drawn in.
 */
export function keyLabelLayout(dots, names, size, measure) {
  const dotBoxes = dots.map(([x, y]) => ({ x: x - DOT_RADIUS, y: y - DOT_RADIUS, w: 2 * DOT_RADIUS, h: 2 * DOT_RADIUS }));
  const placed = [];
  const fit = (text, w) => {
    if (measure(text) <= w) return text;
    let t = text;
    while (t.length > 1 && measure(`${t}…`) > w) t = t.slice(0, -1);
    return `${t}…`;
  };
  names.forEach((name, i) => {
    const [x, y] = dots[i];
    const full = Math.min(measure(name), size);
    const h = LABEL_HEIGHT;
    const r = DOT_RADIUS + LABEL_GAP;
    const clampX = (v, w) => Math.min(size - w, Math.max(0, v));
    const clampY = (v) => Math.min(size - h, Math.max(0, v));
    const spots = (w) => [
      { x: x + r, y: clampY(y - h / 2), w, h },
      { x: x - r - w, y: clampY(y - h / 2), w, h },
      { x: clampX(x - w / 2, w), y: y - r - h, w, h },
      { x: clampX(x - w / 2, w), y: y + r, w, h },
    ].filter((s) => s.x >= 0 && s.y >= 0 && s.x + s.w <= size && s.y + s.h <= size);
    const cost = (s) => [...placed, ...dotBoxes.filter((_, j) => j !== i)].reduce((sum, b) => sum + overlapArea(s, b), 0);
    let best = spots(full).find((s) => cost(s) === 0);
    if (!best) {
      // Shortened: the side with the most room that overlaps nothing, or
      // the least overlapping one.
      const sides = [
        { x: x + r, w: size - (x + r) }, { x: 0, w: x - r },
      ].filter((s) => s.w >= 12).map((s) => ({ x: s.x, y: clampY(y - h / 2), w: Math.min(full, s.w), h }));
      const narrower = sides.map((s) => {
        // Narrow it until it clears the others (at most to 12 px).
        let t = { ...s };
        while (cost(t) > 0 && t.w > 12) t = t.x === x + r ? { ...t, w: t.w - 4 } : { ...t, x: t.x + 4, w: t.w - 4 };
        return t;
      });
      const all = [...spots(full), ...narrower];
      best = all.reduce((a, b) => (cost(b) < cost(a) ? b : a), all[0] ?? { x: clampX(x + r, full), y: clampY(y - h / 2), w: full, h });
    }
    const text = fit(name, best.w);
    const w = Math.min(best.w, measure(text));
    const box = { text, x: best.x, y: best.y, w, h };
    // Right-aligned spots keep their right edge by the dot.
    if (best.x + best.w <= x) box.x = best.x + best.w - w;
    placed.push(box);
  });
  return placed;
}

/** "key N" for the smallest N from the count of keys up that no key is named yet (names must differ). */
export function nextKeyName(keys) {
  const names = new Set(keys.map((k) => k.name));
  let n = keys.length + 1;
  while (names.has(`key ${n}`)) n++;
  return `key ${n}`;
}
