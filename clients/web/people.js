// Who is on stage (the server's `people` message): each connected
// performer and director, and each input source, with a name and a colour
// the server chose from a colour-blind safe palette. Handles and cursors are
// drawn in their owner's colour, and the legend says whose colour is whose.

import { CONFIG_OWNER, KEYS_OWNER, ROLE } from './protocol.js';
import { KEY_COLOUR } from './keypad.js';

/** Pins of the stage file. */
export const CONFIG_COLOUR = '#9e9e9e';
/** An owner the people list does not name (yet). */
export const UNKNOWN_COLOUR = '#bdbdbd';

/** "#E69F00" (or "#e90") as [r, g, b]; null if it is not a hex colour. */
export function parseHex(colour) {
  let m = /^#([0-9a-f]{6})$/i.exec(colour ?? '');
  if (m) {
    const n = parseInt(m[1], 16);
    return [(n >> 16) & 255, (n >> 8) & 255, n & 255];
  }
  m = /^#([0-9a-f]{3})$/i.exec(colour ?? '');
  if (m) return [...m[1]].map((c) => parseInt(c + c, 16));
  return null;
}

/** A CSS colour: `colour` (hex) with `alpha`. */
export function withAlpha(colour, alpha = 1) {
  const rgb = parseHex(colour);
  return rgb ? `rgb(${rgb[0]} ${rgb[1]} ${rgb[2]} / ${alpha})` : colour;
}

export class People {
  constructor() {
    this.list = [];          // the newest people message's list
    this.byOwner = new Map(); // owner -> {owner, name, role, colour}
  }

  /** A `people` message's list. */
  update(list) {
    this.list = Array.isArray(list) ? list : [];
    this.byOwner = new Map(this.list.map((p) => [p.owner, p]));
  }

  /** Forgets everyone (a new connection: its people message follows). */
  clear() {
    this.update([]);
  }

  /** The person or device behind `owner`, or undefined. */
  get(owner) {
    return this.byOwner.get(owner);
  }

  /** The hex colour handles and cursors of `owner` are drawn in. */
  colour(owner) {
    if (owner === CONFIG_OWNER) return CONFIG_COLOUR;
    if (owner === KEYS_OWNER) return KEY_COLOUR;
    return this.byOwner.get(owner)?.colour ?? UNKNOWN_COLOUR;
  }

  /** The colour as CSS with `alpha`. */
  css(owner, alpha = 1) {
    return withAlpha(this.colour(owner), alpha);
  }

  /**
   * Fills `element` with one entry per person (then devices): a swatch in
   * their colour and their name, `you` marking this page's own entry.
   */
  renderLegend(element, you) {
    const order = (p) => (p.role === ROLE.DEVICE ? 1 : 0);
    const people = [...this.list].sort((a, b) => order(a) - order(b));
    element.replaceChildren(...people.map((p) => {
      const entry = document.createElement('span');
      entry.className = 'person';
      entry.dataset.owner = p.owner;
      entry.dataset.role = p.role;
      entry.title = `${p.name} (${p.role})`;
      const swatch = document.createElement('span');
      swatch.className = 'swatch';
      swatch.style.backgroundColor = p.colour;
      const name = document.createElement('span');
      name.className = 'name';
      name.textContent = p.owner === you ? `${p.name} (you)` : p.name;
      entry.append(swatch, name);
      return entry;
    }));
    element.hidden = people.length === 0;
  }
}
