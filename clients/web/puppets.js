// The director's Puppets panel: the stage's puppets in drawing order, each
// with up, down and remove, and adding a picture to the running stage (a
// PNG the daemon meshes with about the vertex count asked for). Whatever
// the daemon answers an upload (the new puppet's mesh and its warnings, or
// why it refused the picture) stays in the panel's notice until dismissed
// or the next upload: a director must see that a picture became a plain
// rectangle, not find it in the console. The panel never changes the
// stage itself: every page, this one too, redraws from the `stage` message
// the daemon sends after each change. The pure pieces (names, vertex
// counts, orders, reading an answer) are exported for the unit tests.

import {
  MAX_PICTURE_BYTES, PUPPET_ADDED, PUPPET_VERTICES,
  addPuppetPath, orderPuppetsMessage, removePuppetMessage,
} from './protocol.js';

/** A puppet's default name: the picture's file name without folder or extension ("puppet" when that leaves nothing). */
export function nameFromFile(fileName) {
  const base = String(fileName ?? '').replace(/^.*[\\/]/, '');
  return base.replace(/\.[^.]*$/, '').trim() || 'puppet';
}

/**
 * The vertex count as typed: {vertices} for a whole number the daemon
 * takes, else {error, field} saying why (the daemon would refuse it too,
 * after the whole picture had been sent).
 */
export function checkVertices(text) {
  const typed = String(text ?? '').trim();
  const v = Number(typed);
  if (typed === '' || !Number.isInteger(v)) return { error: `"${typed}" is not a whole number of vertices`, field: 'vertices' };
  if (v < PUPPET_VERTICES.MIN || v > PUPPET_VERTICES.MAX) {
    return { error: `${v} vertices is out of range (${PUPPET_VERTICES.MIN} to ${PUPPET_VERTICES.MAX})`, field: 'vertices' };
  }
  return { vertices: v };
}

/**
 * `order` (puppet ids, bottom to top) with `id` moved one place: `step` +1
 * draws it over the puppet above it, −1 under the one below. Null when it
 * is not there or already at that end.
 */
export function movedOrder(order, id, step) {
  const from = order.indexOf(id);
  const to = from + step;
  if (from < 0 || to < 0 || to >= order.length) return null;
  const moved = order.slice();
  [moved[from], moved[to]] = [moved[to], moved[from]];
  return moved;
}

/**
 * What the daemon answered an upload: `status` (0: no answer at all) and
 * the body's text, as {answer, notice}. `answer` is the daemon's JSON; an
 * answer that is not JSON (an older daemon's 404, a proxy's page) becomes
 * an `error` of code `http` saying what came. `notice` is what the panel
 * shows: {kind: 'added' | 'warning' | 'error', lines}.
 */
export function readUploadAnswer(status, text) {
  let answer = null;
  try {
    answer = JSON.parse(text);
  } catch { /* not JSON: said below */ }
  if (answer === null || typeof answer !== 'object' || Array.isArray(answer)) {
    answer = { type: 'error', code: 'http', message: httpTrouble(status, text) };
  }
  const ok = status >= 200 && status < 300;
  if (ok && answer.type === PUPPET_ADDED) {
    const warnings = Array.isArray(answer.warnings) ? answer.warnings.map(String) : [];
    const added = `added ${answer.name} (puppet ${answer.puppet}): ${answer.vertices} vertices, ${answer.triangles} triangles`;
    return { answer, notice: { kind: warnings.length ? 'warning' : 'added', lines: [added, ...warnings.map((w) => `warning: ${w}`)] } };
  }
  if (answer.type !== 'error') {
    answer = { type: 'error', code: 'http', message: `unexpected answer (${status}): ${String(text).slice(0, 200)}` };
  }
  return { answer, notice: { kind: 'error', lines: [refusal(answer)] } };
}

/** An `error` answer as one line: the message, the field at fault, the code. */
export function refusal(error) {
  const field = error.field ? ` (field: ${error.field})` : '';
  return `not added: ${error.message ?? 'no reason given'}${field} [${error.code ?? 'error'}]`;
}

// A non-JSON answer, said so a director knows where to look.
function httpTrouble(status, text) {
  if (!status) return 'no answer from the daemon (is it running? is the page on its address?)';
  const body = String(text ?? '').trim().slice(0, 200);
  const older = status === 404 || status === 405 ? ': this daemon cannot add puppets (older than the page?)' : '';
  return `the daemon answered HTTP ${status}${older}${body && !older ? `: ${body}` : ''}`;
}

/**
 * POSTs the picture `file` (a Blob) to `path` as the director (`token`);
 * settles with {status, text} (status 0 when nothing answered). XHR rather
 * than fetch for the upload's progress: onProgress(fraction sent).
 */
export function postPicture(path, token, file, onProgress) {
  return new Promise((resolve) => {
    const xhr = new XMLHttpRequest();
    xhr.open('POST', path);
    xhr.setRequestHeader('Authorization', `Bearer ${token}`);
    xhr.setRequestHeader('Content-Type', 'image/png');
    xhr.upload.onprogress = (e) => { if (e.lengthComputable && e.total) onProgress(e.loaded / e.total); };
    xhr.upload.onload = () => onProgress(1);
    xhr.onload = () => resolve({ status: xhr.status, text: xhr.responseText });
    xhr.onerror = xhr.onabort = xhr.ontimeout = () => resolve({ status: 0, text: '' });
    xhr.send(file);
  });
}

/** Okabe–Ito, as the people list: one colour per piece in turn. */
const PIECE_COLOURS = ['#E69F00', '#56B4E9', '#009E73', '#F0E442', '#0072B2', '#D55E00', '#CC79A7'];

/**
 * The pieces of a mesh (`rest`: x, y pairs; `triangles`: index triples):
 * for each triangle, the piece it is in (triangles sharing a vertex are one).
 */
export function meshPieces(rest, triangles) {
  const parent = Array.from({ length: rest.length / 2 }, (_, i) => i);
  const find = (i) => { while (parent[i] !== i) i = parent[i] = parent[parent[i]]; return i; };
  for (let t = 0; t < triangles.length; t += 3) {
    const a = find(triangles[t]);
    for (const v of [triangles[t + 1], triangles[t + 2]]) parent[find(v)] = a;
  }
  const number = new Map();
  const pieces = [];
  for (let t = 0; t < triangles.length; t += 3) {
    const r = find(triangles[t]);
    if (!number.has(r)) number.set(r, number.size);
    pieces.push(number.get(r));
  }
  return pieces;
}

// A small canvas of a mesh with each piece in its own colour.
function piecesPicture(rest, triangles, size = 160) {
  const canvas = document.createElement('canvas');
  canvas.className = 'puppet-pieces';
  canvas.width = canvas.height = size;
  const xs = rest.filter((_, i) => i % 2 === 0);
  const ys = rest.filter((_, i) => i % 2 === 1);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const scale = (size - 8) / Math.max(x1 - x0, y1 - y0, 1e-9);
  const at = (v) => [4 + (rest[2 * v] - x0) * scale, size - 4 - (rest[2 * v + 1] - y0) * scale];
  const g = canvas.getContext('2d');
  const pieces = meshPieces(rest, triangles);
  canvas.dataset.pieces = String(new Set(pieces).size);
  for (let t = 0; t < triangles.length; t += 3) {
    g.fillStyle = PIECE_COLOURS[pieces[t / 3] % PIECE_COLOURS.length];
    g.beginPath();
    g.moveTo(...at(triangles[t]));
    g.lineTo(...at(triangles[t + 1]));
    g.lineTo(...at(triangles[t + 2]));
    g.fill();
  }
  canvas.title = `${canvas.dataset.pieces} pieces, each in its colour: each moves on its own`;
  return canvas;
}

export class PuppetsPanel {
  /**
   * elements: {panel (its place in the bar), toggle (opens the rest),
   * body, list, file, vertices, name, add, notice, noticeText,
   * noticeClose}. send(message); token(): the director's token;
   * onAnswer(answer): the daemon's answer to an upload; confirm(text):
   * whether to go ahead (window.confirm).
   */
  constructor(elements, { send, token, onAnswer, confirm }) {
    this.el = elements;
    this.send = send;
    this.token = token;
    this.onAnswer = onAnswer;
    this.confirm = confirm;
    this.enabled = false;
    this.puppets = [];        // [{id, name, vertices}] bottom to top, from the stage message
    this.uploading = false;
    const { toggle, file, vertices, add, noticeClose } = elements;
    vertices.min = String(PUPPET_VERTICES.MIN);
    vertices.max = String(PUPPET_VERTICES.MAX);
    vertices.value = String(PUPPET_VERTICES.DEFAULT);
    toggle.addEventListener('click', () => this.setOpen(this.el.body.hidden));
    file.addEventListener('change', () => {
      this.el.name.placeholder = file.files[0] ? nameFromFile(file.files[0].name) : 'name';
    });
    add.addEventListener('click', () => this.upload());
    noticeClose.addEventListener('click', () => this.clearNotice());
    this.setOpen(false);
    this.clearNotice();
    addEventListener('resize', () => this.place());
  }

  /** Shows the panel (directors, not the show view). */
  setEnabled(on) {
    this.enabled = on;
    this.el.panel.hidden = !on;
  }

  setOpen(open) {
    const { body, toggle } = this.el;
    body.hidden = !open;
    toggle.setAttribute('aria-expanded', String(open));
    this.label();
    this.place();
  }

  // Hangs from its button, but never past the window's right edge: the bar
  // wraps and reflows (a new puppet adds its undo group), so this runs on
  // every open, stage message and resize.
  place() {
    const { body } = this.el;
    body.style.left = '0px';
    if (body.hidden) return;
    const right = body.getBoundingClientRect().right;
    if (right > innerWidth - 6) body.style.left = `${innerWidth - 6 - right}px`;
  }

  // The toggle says how many puppets there are, and flags a notice left unread behind it.
  label() {
    const n = this.puppets.length;
    const unread = this.el.body.hidden && !this.el.notice.hidden ? ' ⚠' : '';
    this.el.toggle.textContent = `puppets (${n})${unread} ${this.el.body.hidden ? '▾' : '▴'}`;
  }

  /** A stage message: the puppets, bottom to top. */
  setup(puppets) {
    this.puppets = puppets.map((p) => ({ id: p.id, name: p.src.name, vertices: p.n }));
    this.sources = puppets.map((p) => p.src);
    this.drawPieces();
    const ids = this.puppets.map((p) => p.id);
    // Listed bottom to top as the stage draws them; the stylesheet shows the
    // top one first, so "up" moves an entry up the list.
    this.el.list.replaceChildren(...this.puppets.map((p, i) => {
      const item = document.createElement('li');
      item.dataset.puppet = String(p.id);
      const name = document.createElement('span');
      name.className = 'puppet-name';
      name.textContent = p.name;
      name.title = `puppet ${p.id}, ${p.vertices} vertices`;
      const button = (cls, text, title, disabled, onClick) => {
        const b = document.createElement('button');
        b.type = 'button';
        b.className = cls;
        b.textContent = text;
        b.title = title;
        b.disabled = disabled;
        b.addEventListener('click', onClick);
        return b;
      };
      item.append(
        name,
        button('puppet-up', 'up', `Draw ${p.name} over the puppet above it`, i === ids.length - 1, () => this.move(p.id, +1)),
        button('puppet-down', 'down', `Draw ${p.name} under the puppet below it`, i === 0, () => this.move(p.id, -1)),
        button('puppet-remove', 'remove', `Take ${p.name} off the stage (asks first)`, false, () => this.remove(p)),
      );
      return item;
    }));
    this.label();
    // After the page has rebuilt the rest of the bar for this stage.
    requestAnimationFrame(() => this.place());
  }

  move(id, step) {
    const order = movedOrder(this.puppets.map((p) => p.id), id, step);
    if (order) this.send(orderPuppetsMessage(order));
  }

  remove(p) {
    const sure = this.confirm(`Remove ${p.name} (puppet ${p.id}) from the stage, on every page? Only adding its picture again brings it back, as a new puppet.`);
    if (sure) this.send(removePuppetMessage(p.id));
  }

  /** The notice: `kind` 'added', 'warning' or 'error'; it stays until dismissed or the next upload. */
  showNotice(kind, lines) {
    const { notice, noticeText } = this.el;
    notice.dataset.kind = kind;
    noticeText.replaceChildren(...lines.map((line) => {
      const p = document.createElement('p');
      p.textContent = line;
      return p;
    }));
    notice.hidden = false;
    this.label();
  }

  // A picture of separate pieces was added: each moves on its own. The
  // notice draws them (once the stage message brings the mesh) and offers
  // to add it again with its pieces joined, in place of this one.
  offerJoin(answer) {
    this.split = answer;
    const join = document.createElement('button');
    join.type = 'button';
    join.className = 'puppet-join';
    join.textContent = `join pieces (gaps up to ${answer.join} px)`;
    join.title = `Add ${answer.name} again as one piece (its pieces bridged), in place of this one`;
    join.addEventListener('click', () => {
      this.send(removePuppetMessage(answer.puppet));
      this.upload({ join: answer.join });
    });
    this.el.noticeText.append(join);
    this.drawPieces();
  }

  // The split puppet's pieces in the notice, once its mesh is here (the
  // stage message with it may come before or after the upload's answer).
  drawPieces() {
    const src = this.split && !this.split.drawn && (this.sources ?? []).find((s) => s.id === this.split.puppet);
    if (!src) return;
    this.split.drawn = true;
    this.el.noticeText.append(piecesPicture(src.rest, src.triangles));
  }

  clearNotice() {
    this.el.notice.hidden = true;
    this.el.notice.dataset.kind = '';
    this.el.noticeText.replaceChildren();
    this.label();
  }

  // Sends the chosen picture. What can be told before sending it (no file,
  // too large, a vertex count out of range) is told at once.
  async upload({ join } = {}) {
    if (this.uploading) return;
    this.split = null;
    this.clearNotice();
    const { file, vertices, name, add } = this.el;
    const picture = file.files[0];
    if (!picture) return this.showNotice('error', ['choose a PNG picture first']);
    if (picture.size > MAX_PICTURE_BYTES) {
      const mib = (n) => (n / 1024 / 1024).toFixed(1);
      return this.showNotice('error', [`${picture.name} is ${mib(picture.size)} MiB; the daemon takes at most ${mib(MAX_PICTURE_BYTES)} MiB`]);
    }
    const count = checkVertices(vertices.value);
    if (count.error) return this.showNotice('error', [`${count.error} (field: ${count.field})`]);
    const puppetName = name.value.trim() || nameFromFile(picture.name);
    this.uploading = true;
    add.disabled = true;
    add.textContent = 'uploading…';
    try {
      const path = addPuppetPath({ name: puppetName, vertices: count.vertices, join });
      const { status, text } = await postPicture(path, this.token(), picture, (sent) => {
        // Once every byte is out, the daemon is meshing.
        add.textContent = sent < 1 ? `uploading ${Math.floor(100 * sent)}%` : 'meshing…';
      });
      const { answer, notice } = readUploadAnswer(status, text);
      this.showNotice(notice.kind, notice.lines);
      if (answer.type === PUPPET_ADDED && answer.pieces > 1 && answer.join) this.offerJoin(answer);
      this.onAnswer(answer);
    } finally {
      this.uploading = false;
      add.disabled = false;
      add.textContent = 'add';
    }
  }
}
