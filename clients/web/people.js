// Who is on stage (the server's `people` message): each connected
// performer and director, and each input source, with a name and a colour
// the server chose from a colour-blind safe palette. Handles and cursors are
// drawn in their owner's colour, and the legend says whose colour is whose.
// The legend also shows every source holding contacts now, with how many —
// those the list does not name too (a TUIO sender, a relay's performer) —
// so a director can see a source that went silent mid-touch and let it go.

import { CONFIG_OWNER, HANDLE_KIND, KEYS_OWNER, ROLE } from './protocol.js';
import { KEY_COLOUR } from './keypad.js';

/** Pins of the stage file. */
export const CONFIG_COLOUR = '#9e9e9e';
/** An owner the people list does not name (yet). */
export const UNKNOWN_COLOUR = '#bdbdbd';

/**
 * How many contacts each owner holds, over every puppet's handles
 * (`{puppetId: [handle, …]}`): pins and key handles are not held.
 */
export function holding(handlesByPuppet) {
  const held = new Map();
  for (const handles of Object.values(handlesByPuppet ?? {})) {
    for (const h of handles ?? []) {
      if (h.kind !== HANDLE_KIND.CONTACT) continue;
      held.set(h.owner, (held.get(h.owner) ?? 0) + 1);
    }
  }
  return held;
}

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
   * `held` (owner -> contacts held, see `holding`) adds how many each
   * holds, and an entry for a holder the list does not name; with
   * `release(owner)` (a director's page) each holder other than this page
   * gets a button that lets it go.
   */
  renderLegend(element, you, held = new Map(), release = null) {
    const order = (p) => (p.role === ROLE.DEVICE ? 1 : 0);
    const unnamed = [...held.keys()]
      .filter((owner) => !this.byOwner.has(owner))
      .sort()
      .map((owner) => ({ owner, name: owner, role: ROLE.DEVICE, colour: UNKNOWN_COLOUR }));
    const people = [...this.list, ...unnamed].sort((a, b) => order(a) - order(b));
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
      const count = held.get(p.owner) ?? 0;
      if (count > 0) {
        const holds = document.createElement('span');
        holds.className = 'holds';
        holds.textContent = `✋${count}`;
        holds.title = `${p.name} holds ${count} contact${count === 1 ? '' : 's'}`;
        entry.append(holds);
        if (release && p.owner !== you) {
          const letGo = document.createElement('button');
          letGo.className = 'let-go';
          letGo.textContent = '×';
          letGo.title = `Let go of what ${p.name} holds (a sender gone silent, a stuck device)`;
          letGo.addEventListener('click', () => release(p.owner));
          entry.append(letGo);
        }
      }
      return entry;
    }));
    element.hidden = people.length === 0;
  }
}
