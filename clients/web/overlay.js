// The 2D overlay over the GL picture (#overlay): rigs (deformed grid,
// skeleton bones and joints), the painted stiffness tint and brush, every
// handle in its owner's colour (pins, contacts, the keyframing cursor's key
// handles as diamonds) where it is on the solved puppet now, this page's
// own pointers, calibration marks and mouse cursors. It only draws what it
// is given, and keeps a list of the dots it drew (for tests).

import { HANDLE_GRIP, HANDLE_KIND, RIG_KIND } from './protocol.js';
import { KEY_COLOUR } from './keypad.js';

/**
 * Where handle `i` of puppet state `p` is now (stage point), or null when
 * only the pointer knows (our own contact before its first handle frame).
 * The newest handle frame of the handle set's generation says it; until one
 * comes, key handles follow their anchor on the mesh and other handles
 * stay where they were held when the set changed (`at`). Our own contacts
 * are not drawn at `at`: it goes stale as the pointer moves on.
 */
export function handleAt(p, i, myOwner) {
  const h = p.handles[i];
  const f = p.handleFrame;
  if (f && f.generation === p.handlesGeneration && f.points.length === 2 * p.handles.length) {
    return [f.points[2 * i], f.points[2 * i + 1]];
  }
  if (h.kind === HANDLE_KIND.KEY) {
    const anchor = p.keyAnchors?.get(h.id);
    return (anchor && anchorPoint(anchor, p.positions, p.rigPoints)) ?? h.at;
  }
  if (h.kind === HANDLE_KIND.CONTACT && h.owner === myOwner) return null;
  return h.at;
}

/**
 * Where a key handle is drawn as the mesh moves. A `handles` message gives
 * a handle's `at` only when the set changes, but key handles keep moving
 * while the pad's cursor does, with no message. They hold material points
 * (or grid handles, joints), so the handle is pinned to the mesh where it
 * was: the triangle under `at` in the positions then, and its barycentric
 * weights; or the rig point it holds. Null when nothing can be found.
 */
export function keyHandleAnchor(handle, positions, triangles) {
  if ((handle.grip === HANDLE_GRIP.GRID || handle.grip === HANDLE_GRIP.JOINT) && Number.isInteger(handle.index)) {
    return { rig: handle.index };
  }
  const [x, y] = handle.at;
  // The triangle containing the point, or failing that (a point a hair
  // outside the mesh) the one it is least outside of.
  let best = null;
  let bestOutside = Infinity;
  for (let t = 0; t < triangles.length; t += 3) {
    const a = triangles[t], b = triangles[t + 1], c = triangles[t + 2];
    const ax = positions[2 * a], ay = positions[2 * a + 1];
    const bx = positions[2 * b], by = positions[2 * b + 1];
    const cx = positions[2 * c], cy = positions[2 * c + 1];
    const det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy);
    if (det === 0) continue;
    const wa = ((by - cy) * (x - cx) + (cx - bx) * (y - cy)) / det;
    const wb = ((cy - ay) * (x - cx) + (ax - cx) * (y - cy)) / det;
    const wc = 1 - wa - wb;
    const outside = Math.max(0, -wa, -wb, -wc);
    if (outside < bestOutside) {
      bestOutside = outside;
      best = { a, b, c, wa, wb, wc };
      if (outside === 0) break;
    }
  }
  return best;
}

/** The stage point of an anchor from keyHandleAnchor, given the newest positions and rig points. */
export function anchorPoint(anchor, positions, rigPoints) {
  if (anchor.rig !== undefined) {
    if (!rigPoints || 2 * anchor.rig + 1 >= rigPoints.length) return null;
    return [rigPoints[2 * anchor.rig], rigPoints[2 * anchor.rig + 1]];
  }
  const { a, b, c, wa, wb, wc } = anchor;
  return [
    wa * positions[2 * a] + wb * positions[2 * b] + wc * positions[2 * c],
    wa * positions[2 * a + 1] + wb * positions[2 * b + 1] + wc * positions[2 * c + 1],
  ];
}

/** Bernstein polynomials of degree `d` at `x` (de Casteljau's recurrence). */
function bernstein(d, x) {
  const b = new Array(d + 1).fill(0);
  b[0] = 1;
  for (let j = 1; j <= d; j++) {
    for (let k = j; k >= 1; k--) b[k] = (1 - x) * b[k] + x * b[k - 1];
    b[0] *= 1 - x;
  }
  return b;
}

/**
 * The lines of an m × n Bernstein grid's lattice through its map
 * f(s, t) = Σ B_c(s) B_r(t) P_rc (handles `q`, row-major, x y pairs):
 * each row and column as polylines of `k` points per cell, cut where
 * `keep(s, t)` (if given) is false.
 */
export function bernsteinGridLines(q, m, n, k = 8, keep = null) {
  const f = (s, t) => {
    const bs = bernstein(m - 1, s);
    const bt = bernstein(n - 1, t);
    let x = 0;
    let y = 0;
    for (let r = 0; r < n; r++) {
      for (let c = 0; c < m; c++) {
        const w = bs[c] * bt[r];
        x += w * q[2 * (r * m + c)];
        y += w * q[2 * (r * m + c) + 1];
      }
    }
    return [x, y];
  };
  const lines = [];
  const along = k * (m - 1);
  const down = k * (n - 1);
  const trace = (count, st) => {
    let run = [];
    for (let i = 0; i <= count; i++) {
      const [u, v] = st(i / count);
      if (keep && !keep(u, v)) {
        if (run.length > 1) lines.push(run);
        run = [];
      } else run.push(f(u, v));
    }
    if (run.length > 1) lines.push(run);
  };
  for (let r = 0; r < n; r++) trace(along, (x) => [x, r / (n - 1)]);
  for (let c = 0; c < m; c++) trace(down, (x) => [c / (m - 1), x]);
  return lines;
}

/**
 * Whether a point (s, t) of a grid's box is on its puppet: within three
 * quarters of a cell of a rest vertex (`rest`, x y pairs, stage
 * coordinates; the map is the identity at rest).
 */
function gridKeep(rig, rest, m, n) {
  const [x0, y0] = rig.min;
  const [x1, y1] = rig.max;
  const reach = 0.5 * Math.min((x1 - x0) / (m - 1), (y1 - y0) / (n - 1));
  const cells = new Map();
  const key = (i, j) => `${i},${j}`;
  for (let v = 0; v < rest.length / 2; v++) {
    const i = Math.floor(rest[2 * v] / reach);
    const j = Math.floor(rest[2 * v + 1] / reach);
    if (!cells.has(key(i, j))) cells.set(key(i, j), []);
    cells.get(key(i, j)).push(v);
  }
  return (s, t) => {
    const x = x0 + s * (x1 - x0);
    const y = y0 + t * (y1 - y0);
    const i = Math.floor(x / reach);
    const j = Math.floor(y / reach);
    for (let di = -1; di <= 1; di++) {
      for (let dj = -1; dj <= 1; dj++) {
        for (const v of cells.get(key(i + di, j + dj)) ?? []) {
          if (Math.hypot(rest[2 * v] - x, rest[2 * v + 1] - y) <= reach) return true;
        }
      }
    }
    return false;
  };
}

/** A lattice grid's rows and columns: its handles are its nodes. */
function latticeLines(q, m, n) {
  const at = (i) => [q[2 * i], q[2 * i + 1]];
  const lines = [];
  for (let r = 0; r < n; r++) lines.push(Array.from({ length: m }, (_, c) => at(r * m + c)));
  for (let c = 0; c < m; c++) lines.push(Array.from({ length: n }, (_, r) => at(r * m + c)));
  return lines;
}

export class Overlay {
  /** canvas: the overlay canvas; stageElement: the letterboxed stage it covers. */
  constructor(canvas, stageElement) {
    this.canvas = canvas;
    this.stageElement = stageElement;
    this.ctx = canvas.getContext('2d');
  }

  /**
   * Draws the whole overlay afresh from `scene`:
   *   puppets           puppet states (handles, keyAnchors, rig, rigPoints, weights, positions, src.triangles)
   *   cursors           the newest "cursors" message's list
   *   myOwner           "client:N": our own contacts come from ownContacts instead
   *   ownContacts       stage points {x, y} of our pointers that hold contacts
   *   showWeights       tint triangles by painted stiffness (while the paint tool is on)
   *   brush             {x, y, radius, stiffens} or null: the paint brush outline
   *   sketch            {points, width, colour} or null: the curve being drawn
   *   calibrationMarks  stage points to mark 1, 2, 3, 4, or null
   *   stageToClient     (x, y) -> [clientX, clientY]
   *   colour            (owner, alpha) -> CSS colour of the owner's handles and cursors
   *   pads              the stage's key pad areas: {puppet, name, area: [x0, y0, x1, y1], source?, keys, cursor?}
   *   rigs              draw rigs (not in the show view)
   *   handles           draw handles, own pointers and cursors
   */
  draw(scene) {
    const { ctx, canvas } = this;
    const { stageToClient } = scene;
    this.drawn = [];
    const dpr = canvas.width / this.stageElement.clientWidth || 1;
    const r = this.stageElement.getBoundingClientRect();
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    // Overlay pixels (CSS) of a stage point.
    const toOverlay = (x, y) => {
      const [cx, cy] = stageToClient(x, y);
      return [cx - r.left, cy - r.top];
    };
    const dot = (x, y, radius, fill, ring) => {
      const [px, py] = toOverlay(x, y);
      ctx.beginPath();
      ctx.arc(px, py, radius, 0, 2 * Math.PI);
      if (fill) { ctx.fillStyle = fill; ctx.fill(); }
      ctx.lineWidth = 2;
      ctx.strokeStyle = ring;
      ctx.stroke();
    };
    const line = (ax, ay, bx, by) => {
      const [x0, y0] = toOverlay(ax, ay);
      const [x1, y1] = toOverlay(bx, by);
      ctx.moveTo(x0, y0);
      ctx.lineTo(x1, y1);
    };

    if (scene.rigs !== false) this.drawRigs(scene.puppets, dot, line);
    if (scene.showWeights) this.drawWeights(scene.puppets, toOverlay);
    if (scene.brush) this.drawBrush(scene.brush, toOverlay);
    if (scene.sketch) this.drawSketch(scene.sketch, toOverlay);
    for (const disc of scene.replace ?? []) this.drawReplace(disc, toOverlay);
    this.padsDrawn = [];
    for (const pad of scene.pads ?? []) this.drawPad(pad, toOverlay);
    if (scene.handles !== false) this.drawHandles(scene, dot, toOverlay);
    if (scene.calibrationMarks) this.drawCalibrationMarks(scene.calibrationMarks, toOverlay);
    if (scene.handles !== false) this.drawCursors(scene.cursors, scene.colour, toOverlay, dot);
  }

  // Rigs under the handles: the deformed grid (lines and handle dots) and
  // the skeleton (bones and joints).
  drawRigs(puppets, dot, line) {
    const ctx = this.ctx;
    this.rigLines = [];
    for (const p of puppets) {
      const q = p.rigPoints;
      if (!q) continue;
      const at = (i) => [q[2 * i], q[2 * i + 1]];
      ctx.beginPath();
      if (p.rig.kind === RIG_KIND.GRID) {
        const { columns: m, rows: n } = p.rig;
        // A Bernstein grid's handles are the control points of its map,
        // off the puppet where no vertex holds them: joined up, they
        // tangled after one drag. Its lattice lines carried through the
        // map stay readable (and at rest are the rest grid).
        // Only where the puppet is: elsewhere in its box nothing holds
        // the map, which may fold there after a drag.
        if (p.rig.basis === 'bernstein' && !p.gridKeep) p.gridKeep = gridKeep(p.rig, p.src.rest, m, n);
        const lines = p.rig.basis === 'bernstein'
          ? bernsteinGridLines(q, m, n, 8, p.gridKeep)
          : latticeLines(q, m, n);
        this.rigLines.push({ puppet: p.id, lines });
        for (const polyline of lines) {
          for (let i = 1; i < polyline.length; i++) line(...polyline[i - 1], ...polyline[i]);
        }
        ctx.lineWidth = 1;
        ctx.strokeStyle = 'rgb(41 98 255 / 0.6)';
      } else if (p.rig.kind === RIG_KIND.SKELETON) {
        for (const [a, b] of p.rig.bones) line(...at(a), ...at(b));
        ctx.lineWidth = 4;
        ctx.strokeStyle = 'rgb(255 111 0 / 0.75)';
      }
      ctx.stroke();
      const count = q.length / 2;
      for (let i = 0; i < count; i++) {
        const [x, y] = at(i);
        if (p.rig.kind === RIG_KIND.GRID) dot(x, y, 3, 'rgb(41 98 255 / 0.8)', 'rgb(255 255 255 / 0.8)');
        else dot(x, y, 5, 'rgb(255 111 0 / 0.9)', '#000');
      }
    }
  }

  // Painted stiffness: stiffer blue, softer red, stronger the further
  // from the default weight 1 (on a log scale).
  drawWeights(puppets, toOverlay) {
    const ctx = this.ctx;
    for (const p of puppets) {
      if (!p.weights) continue;
      const v = p.positions;
      const t = p.src.triangles;
      for (let k = 0; k < p.weights.length; k++) {
        const w = p.weights[k];
        if (w === 1) continue;
        const strength = Math.min(1, Math.abs(Math.log10(w)) / 3);
        ctx.fillStyle = w > 1 ? `rgb(41 98 255 / ${0.15 + 0.5 * strength})` : `rgb(213 0 0 / ${0.15 + 0.5 * strength})`;
        ctx.beginPath();
        for (let c = 0; c < 3; c++) {
          const i = t[3 * k + c];
          const [x, y] = toOverlay(v[2 * i], v[2 * i + 1]);
          if (c === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
        }
        ctx.fill();
      }
    }
  }

  // A part the next overdub re-records: a dashed red disc.
  drawReplace(disc, toOverlay) {
    const ctx = this.ctx;
    const [cx, cy] = toOverlay(disc.x, disc.y);
    const [ex] = toOverlay(disc.x + disc.radius, disc.y);
    ctx.save();
    ctx.beginPath();
    ctx.setLineDash([6, 4]);
    ctx.lineWidth = 2;
    ctx.strokeStyle = '#ff5252';
    ctx.arc(cx, cy, Math.abs(ex - cx), 0, 2 * Math.PI);
    ctx.stroke();
    ctx.restore();
  }

  // The stroke being drawn with the curve tool, at its width and colour.
  drawSketch({ points, width, colour }, toOverlay) {
    const ctx = this.ctx;
    const [x0] = toOverlay(0, 0);
    const [x1] = toOverlay(width, 0);
    ctx.beginPath();
    points.forEach(([x, y], i) => {
      const [px, py] = toOverlay(x, y);
      if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
    });
    ctx.lineWidth = Math.max(1, Math.abs(x1 - x0));
    ctx.lineCap = 'round';
    ctx.lineJoin = 'round';
    ctx.strokeStyle = colour;
    ctx.globalAlpha = 0.6;
    ctx.stroke();
    ctx.globalAlpha = 1;
  }

  // The brush's reach: blue while it stiffens, red while it softens.
  drawBrush(brush, toOverlay) {
    const ctx = this.ctx;
    const [cx, cy] = toOverlay(brush.x, brush.y);
    const [ex] = toOverlay(brush.x + brush.radius, brush.y);
    ctx.beginPath();
    ctx.arc(cx, cy, Math.abs(ex - cx), 0, 2 * Math.PI);
    ctx.lineWidth = 1.5;
    ctx.strokeStyle = brush.stiffens ? '#2962ff' : '#d50000';
    ctx.stroke();
  }

  // Handles in their owners' colours where they are on the puppet now (see
  // handleAt); then this page's pointers that hold contacts, as rings in
  // our colour, where they are now.
  drawHandles({ puppets, myOwner, ownContacts, colour }, dot, toOverlay) {
    for (const p of puppets) {
      p.handles.forEach((h, i) => {
        const at = handleAt(p, i, myOwner);
        if (!at) return;
        const fill = colour(h.owner, h.kind === HANDLE_KIND.CONTACT ? 0.75 : 1);
        if (h.kind === HANDLE_KIND.KEY) this.drawDiamond(toOverlay(at[0], at[1]));
        else if (h.kind === HANDLE_KIND.PIN) dot(at[0], at[1], 6, fill, '#000');
        else dot(at[0], at[1], 10, fill, 'rgb(0 0 0 / 0.7)');
        this.drawn.push({ puppet: p.id, handle: h.id, owner: h.owner, kind: h.kind, at: [at[0], at[1]], colour: colour(h.owner) });
      });
    }
    for (const { x, y } of ownContacts) {
      const [px, py] = toOverlay(x, y);
      const ctx = this.ctx;
      ctx.beginPath();
      ctx.arc(px, py, 14, 0, 2 * Math.PI);
      ctx.lineWidth = 2.5;
      ctx.strokeStyle = colour(myOwner, 0.9);
      ctx.stroke();
    }
  }

  // A key handle: a small diamond in the pad's key colour, unlike the round
  // dots of hands and pins, since no hand holds it (the pad's cursor does).
  drawDiamond([px, py]) {
    const ctx = this.ctx;
    const r = 7;
    ctx.beginPath();
    ctx.moveTo(px, py - r); ctx.lineTo(px + r, py); ctx.lineTo(px, py + r); ctx.lineTo(px - r, py);
    ctx.closePath();
    ctx.fillStyle = KEY_COLOUR;
    ctx.fill();
    ctx.lineWidth = 1.5;
    ctx.strokeStyle = '#000';
    ctx.stroke();
  }

  // A `[[pad]]` of the stage file: a contact landing in it moves the
  // puppet's key cursor instead of grabbing, so it must not look like bare
  // stage. Its area (dashed, in the key colour), what it drives, its keys
  // and the cursor, as the key pad panel draws them.
  drawPad({ puppet, name, area, source, keys, cursor }, toOverlay) {
    const ctx = this.ctx;
    const [x0, y0] = toOverlay(area[0], area[3]);
    const [x1, y1] = toOverlay(area[2], area[1]);
    const w = x1 - x0, h = y1 - y0;
    this.padsDrawn.push({ puppet, area: [...area] });
    ctx.save();
    ctx.fillStyle = 'rgb(255 171 0 / 0.08)';
    ctx.fillRect(x0, y0, w, h);
    ctx.setLineDash([6, 4]);
    ctx.lineWidth = 2;
    ctx.strokeStyle = KEY_COLOUR;
    ctx.strokeRect(x0, y0, w, h);
    ctx.setLineDash([]);
    ctx.font = '11px system-ui, sans-serif';
    ctx.textBaseline = 'top';
    ctx.textAlign = 'left';
    ctx.fillStyle = KEY_COLOUR;
    ctx.fillText(`key pad: ${name}${source ? ` (${source})` : ''}`, x0 + 4, y0 + 4, Math.max(10, w - 8));
    const at = ([u, v]) => [x0 + u * w, y0 + (1 - v) * h];
    for (const k of keys ?? []) {
      const [px, py] = at(k.at);
      ctx.beginPath();
      ctx.arc(px, py, 3, 0, 2 * Math.PI);
      ctx.fill();
    }
    if (cursor) {
      const [px, py] = at(cursor);
      ctx.strokeStyle = '#00e5ff';
      ctx.beginPath();
      ctx.arc(px, py, 6, 0, 2 * Math.PI);
      ctx.stroke();
    }
    ctx.restore();
  }

  // Red crosses, numbered in the order to touch them.
  drawCalibrationMarks(marks, toOverlay) {
    const ctx = this.ctx;
    ctx.font = 'bold 20px sans-serif';
    marks.forEach(([x, y], i) => {
      const [px, py] = toOverlay(x, y);
      ctx.lineWidth = 2;
      ctx.strokeStyle = '#e00';
      ctx.beginPath();
      ctx.moveTo(px - 20, py); ctx.lineTo(px + 20, py);
      ctx.moveTo(px, py - 20); ctx.lineTo(px, py + 20);
      ctx.stroke();
      ctx.fillStyle = '#e00';
      ctx.fillText(String(i + 1), px + 8, py - 8);
    });
  }

  // Mice on the stage: a cross at the cursor and the pair of points it
  // holds (filled while its button is down).
  drawCursors(cursors, ownerColour, toOverlay, dot) {
    const ctx = this.ctx;
    for (const c of cursors) {
      const [px, py] = toOverlay(c.at[0], c.at[1]);
      const colour = ownerColour(c.source);
      this.drawn.push({ cursor: c.source, at: [c.at[0], c.at[1]], colour });
      ctx.lineWidth = 2;
      ctx.strokeStyle = colour;
      ctx.beginPath();
      ctx.moveTo(px - 8, py); ctx.lineTo(px + 8, py);
      ctx.moveTo(px, py - 8); ctx.lineTo(px, py + 8);
      ctx.stroke();
      if (c.spacing > 0) {
        const dx = Math.cos(c.angle) * c.spacing / 2, dy = Math.sin(c.angle) * c.spacing / 2;
        for (const s of [-1, 1]) {
          dot(c.at[0] + s * dx, c.at[1] + s * dy, 6, c.holding ? ownerColour(c.source, 0.7) : null, colour);
        }
      }
    }
  }
}
