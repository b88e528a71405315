// Unit tests of the page's pure pieces (no browser): the address's view
// options and token handling, the latency median, owner colours, the
// handle frame header and where a handle is drawn, the puppets panel's
// names, vertex counts, orders and reading of the daemon's answers; which
// pointers hold the stage (contacts and pointers a tool took); and the
// tests' own PNG writer and reader (the mock checks uploads with it).
//
//   node --test unit.test.mjs

import test from 'node:test';
import assert from 'node:assert/strict';

import { FRAME_KIND, decodeFrameHeader, framePoints, paintMessage, pingMessage } from '../../clients/web/protocol.js';
import { TOKEN_KEY, forgetToken, parseSize, takeAccess, viewOptions } from '../../clients/web/session.js';
import { FpsMeter, LatencyMeter, median } from '../../clients/web/hud.js';
import { CONFIG_COLOUR, People, UNKNOWN_COLOUR, parseHex, withAlpha } from '../../clients/web/people.js';
import { handleAt } from '../../clients/web/overlay.js';
import { addPuppetPath, orderPuppetsMessage, removePuppetMessage } from '../../clients/web/protocol.js';
import { checkVertices, movedOrder, nameFromFile, readUploadAnswer } from '../../clients/web/puppets.js';
import { PointerContacts } from '../../clients/web/input.js';
import { keyLabelLayout } from '../../clients/web/keypad.js';
import { describePng, encodePng } from './png.mjs';

// sessionStorage's interface over a Map.
function storage(entries = {}) {
  const m = new Map(Object.entries(entries));
  return {
    getItem: (k) => (m.has(k) ? m.get(k) : null),
    setItem: (k, v) => m.set(k, String(v)),
    removeItem: (k) => m.delete(k),
    map: m,
  };
}

test('view options: the show view, transparency, a fixed size, dots', () => {
  const o = viewOptions(new URLSearchParams('view=show&background=transparent&size=1920x1080'));
  assert.deepEqual(o, { show: true, transparent: true, size: { width: 1920, height: 1080 }, dots: false });
  assert.equal(viewOptions(new URLSearchParams('view=show&dots=1')).dots, true);
  const page = viewOptions(new URLSearchParams('role=performer'));
  assert.deepEqual(page, { show: false, transparent: false, size: null, dots: true });
});

test('sizes: WxH within 1…16384, anything else is none', () => {
  assert.deepEqual(parseSize('1280x720'), { width: 1280, height: 720 });
  for (const bad of ['', null, '0x720', '1280', '1280x', 'x720', '99999x1', '-1x5', '12.5x3', '1280x720x3']) {
    assert.equal(parseSize(bad), null, String(bad));
  }
});

test('a token in the address moves to storage and out of the address', () => {
  const s = storage();
  const replaced = [];
  const a = takeAccess({ href: 'http://h/?role=performer&token=s3cret&calibrate' }, s, (u) => replaced.push(u));
  assert.deepEqual(a, { role: 'performer', token: 's3cret' });
  assert.equal(s.getItem(TOKEN_KEY), 's3cret');
  assert.deepEqual(replaced, ['http://h/?role=performer&calibrate=']);
  // A reload: the address has the role only, the token comes from storage.
  const again = takeAccess({ href: replaced[0] }, s, () => assert.fail('nothing to replace'));
  assert.deepEqual(again, { role: 'performer', token: 's3cret' });
});

test('directors ask as directors; viewers and the show view never send a token', () => {
  const s = storage({ [TOKEN_KEY]: 'kept' });
  assert.deepEqual(takeAccess({ href: 'http://h/?role=director' }, s, () => {}), { role: 'director', token: 'kept' });
  assert.deepEqual(takeAccess({ href: 'http://h/' }, s, () => {}), { role: 'viewer', token: '' });
  assert.deepEqual(takeAccess({ href: 'http://h/?role=nonsense' }, s, () => {}), { role: 'viewer', token: '' });
  const replaced = [];
  const show = takeAccess({ href: 'http://h/?view=show&role=performer&token=t' }, s, (u) => replaced.push(u), { show: true });
  assert.deepEqual(show, { role: 'viewer', token: '' });
  assert.deepEqual(replaced, ['http://h/?view=show&role=performer'], 'the token leaves the address even so');
});

test('a refused token is forgotten', () => {
  const s = storage({ [TOKEN_KEY]: 'wrong' });
  forgetToken(s);
  assert.deepEqual(takeAccess({ href: 'http://h/?role=performer' }, s, () => {}), { role: 'performer', token: '' });
});

test('storage that throws costs only the token across reloads', () => {
  const broken = { getItem() { throw new Error('denied'); }, setItem() { throw new Error('denied'); }, removeItem() { throw new Error('denied'); } };
  assert.deepEqual(takeAccess({ href: 'http://h/?role=performer&token=t' }, broken, () => {}), { role: 'performer', token: 't' });
  assert.deepEqual(takeAccess({ href: 'http://h/?role=performer' }, broken, () => {}), { role: 'performer', token: '' });
  forgetToken(broken);
});

test('latency: the median of the last few round trips', () => {
  assert.equal(median([]), null);
  assert.equal(median([5]), 5);
  assert.equal(median([9, 1, 5]), 5);
  assert.equal(median([4, 1, 3, 2]), 2.5);
  const m = new LatencyMeter(3);
  assert.equal(m.ms, null);
  for (const v of [10, 500, 12]) m.add(v);
  assert.equal(m.ms, 12, 'one slow answer does not move it');
  m.add(14);
  m.add(NaN);
  m.add(-3);
  assert.deepEqual(m.samples, [500, 12, 14]);
  m.add(11);
  assert.equal(m.ms, 12);
});

test('frames per second over the last whole second', () => {
  const f = new FpsMeter();
  let updated = false;
  for (let i = 0; i <= 60; i++) updated = f.tick(i * (1000 / 60)) || updated;
  assert.equal(updated, true);
  assert.equal(f.fps, 60);
});

test('owner colours come from the people list; others are neutral', () => {
  const p = new People();
  p.update([
    { owner: 'client:3', name: 'Ana', role: 'performer', colour: '#E69F00' },
    { owner: 'grid-play', name: 'grid-play', role: 'device', colour: '#999999' },
  ]);
  assert.equal(p.colour('client:3'), '#E69F00');
  assert.equal(p.colour('grid-play'), '#999999');
  assert.equal(p.colour('config'), CONFIG_COLOUR);
  assert.equal(p.colour('client:4'), UNKNOWN_COLOUR);
  assert.equal(p.css('client:3', 0.5), 'rgb(230 159 0 / 0.5)');
  assert.deepEqual(parseHex('#0af'), [0, 170, 255]);
  assert.equal(parseHex('red'), null);
  assert.equal(withAlpha('red', 0.5), 'red');
  p.update(undefined);
  assert.equal(p.colour('client:3'), UNKNOWN_COLOUR);
});

// A handle frame as the daemon writes it.
function handleFrame(puppet, sequence, generation, points) {
  const buf = new ArrayBuffer(32 + 4 * points.length);
  const v = new DataView(buf);
  v.setUint32(0, FRAME_KIND.HANDLES, true);
  v.setUint32(4, puppet, true);
  v.setBigUint64(8, BigInt(sequence), true);
  v.setFloat64(16, 1.5, true);
  v.setUint32(24, points.length / 2, true);
  v.setUint32(28, generation, true);
  points.forEach((x, i) => v.setFloat32(32 + 4 * i, x, true));
  return buf;
}

test('a handle frame header carries the handle set generation', () => {
  const buf = handleFrame(2, 77, 9, [1, 2, 3, 4]);
  const h = decodeFrameHeader(buf);
  assert.deepEqual(h, { kind: 3, puppet: 2, sequence: 77, inputTime: 1.5, count: 2, generation: 9 });
  assert.deepEqual([...framePoints(buf, h)], [1, 2, 3, 4]);
});

test('handles are drawn at the handle frame of their generation, else where they were', () => {
  const handles = [
    { id: 1, owner: 'client:3', kind: 'contact', at: [10, 10], grip: 'point' },
    { id: 2, owner: 'client:4', kind: 'contact', at: [20, 20], grip: 'point' },
    { id: 3, owner: 'config', kind: 'pin', at: [30, 30], grip: 'point' },
  ];
  const p = { handles, handlesGeneration: 5, handleFrame: null, keyAnchors: new Map(), positions: [], rigPoints: null };
  // No frame yet: others' handles where they were held; our own is the pointer's.
  assert.equal(handleAt(p, 0, 'client:3'), null);
  assert.deepEqual(handleAt(p, 1, 'client:3'), [20, 20]);
  // A frame of this generation: everyone's handles where they are now.
  p.handleFrame = { generation: 5, sequence: 1, points: new Float32Array([11, 12, 25, 26, 30, 30]) };
  assert.deepEqual(handleAt(p, 0, 'client:3'), [11, 12]);
  assert.deepEqual(handleAt(p, 1, 'client:3'), [25, 26]);
  assert.deepEqual(handleAt(p, 2, 'client:3'), [30, 30]);
  // A frame of another generation (or count) names other handles: not used.
  p.handleFrame = { generation: 4, sequence: 2, points: new Float32Array([0, 0, 0, 0, 0, 0]) };
  assert.deepEqual(handleAt(p, 1, 'client:3'), [20, 20]);
  p.handleFrame = { generation: 5, sequence: 2, points: new Float32Array([0, 0]) };
  assert.deepEqual(handleAt(p, 1, 'client:3'), [20, 20]);
});

test('messages: pings carry their time, paint dabs their stroke', () => {
  assert.deepEqual(pingMessage(12.5), { type: 'ping', t: 12.5 });
  assert.deepEqual(paintMessage(0, 1, 2, 3, 1.5, 7), { type: 'paint', puppet: 0, x: 1, y: 2, radius: 3, strength: 1.5, stroke: 7 });
  assert.equal('stroke' in paintMessage(0, 1, 2, 3, 1.5), false);
});

test('a new puppet is named after its picture', () => {
  assert.equal(nameFromFile('figure.png'), 'figure');
  assert.equal(nameFromFile('C:\\pictures\\Hans im Glück.PNG'), 'Hans im Glück');
  assert.equal(nameFromFile('/tmp/a.b.png'), 'a.b');
  assert.equal(nameFromFile('noextension'), 'noextension');
  for (const nothing of ['.png', '', undefined, '  .png']) assert.equal(nameFromFile(nothing), 'puppet', String(nothing));
});

test('vertex counts: whole numbers from 50 to 20000', () => {
  assert.deepEqual(checkVertices('300'), { vertices: 300 });
  assert.deepEqual(checkVertices(' 50 '), { vertices: 50 });
  assert.deepEqual(checkVertices(20000), { vertices: 20000 });
  for (const bad of ['49', '20001', '300.5', '', 'many', '-300', null]) {
    const r = checkVertices(bad);
    assert.equal(r.field, 'vertices', String(bad));
    assert.ok(r.error, String(bad));
  }
});

test('moving a puppet swaps it with its neighbour in the drawing order', () => {
  assert.deepEqual(movedOrder([0, 4, 7], 4, +1), [0, 7, 4]);
  assert.deepEqual(movedOrder([0, 4, 7], 4, -1), [4, 0, 7]);
  assert.equal(movedOrder([0, 4, 7], 7, +1), null, 'the top one cannot go higher');
  assert.equal(movedOrder([0, 4, 7], 0, -1), null, 'the bottom one cannot go lower');
  assert.equal(movedOrder([0, 4, 7], 5, +1), null, 'not on stage');
  const order = [0, 4, 7];
  movedOrder(order, 4, 1);
  assert.deepEqual(order, [0, 4, 7], 'the order given is left alone');
});

test('messages and the address that add, remove and reorder puppets', () => {
  assert.deepEqual(removePuppetMessage(3), { type: 'remove_puppet', puppet: 3 });
  assert.deepEqual(orderPuppetsMessage([3, 0]), { type: 'order_puppets', order: [3, 0] });
  assert.equal(addPuppetPath({ name: 'Hans & Grete', vertices: 300 }), '/puppets?name=Hans+%26+Grete&vertices=300');
  assert.equal(addPuppetPath({ name: 'a', vertices: 50, x: 640, y: 0, scale: 0.5 }), '/puppets?name=a&vertices=50&x=640&y=0&scale=0.5');
});

test('the daemon\'s answers to an upload, as the panel shows them', () => {
  const added = { type: 'puppet_added', puppet: 3, name: 'figure', vertices: 297, triangles: 520, warnings: [] };
  let r = readUploadAnswer(200, JSON.stringify(added));
  assert.deepEqual(r.answer, added);
  assert.equal(r.notice.kind, 'added');
  assert.deepEqual(r.notice.lines, ['added figure (puppet 3): 297 vertices, 520 triangles']);

  const opaque = 'every pixel is opaque (no transparent background), so the puppet is the whole 200×100 rectangle';
  r = readUploadAnswer(200, JSON.stringify({ ...added, warnings: [opaque] }));
  assert.equal(r.notice.kind, 'warning');
  assert.equal(r.notice.lines[1], `warning: ${opaque}`);

  const refused = { type: 'error', code: 'out_of_range', message: 'vertices: 10 is out of range', field: 'vertices' };
  r = readUploadAnswer(400, JSON.stringify(refused));
  assert.deepEqual(r.answer, refused);
  assert.equal(r.notice.kind, 'error');
  assert.deepEqual(r.notice.lines, ['not added: vertices: 10 is out of range (field: vertices) [out_of_range]']);
  r = readUploadAnswer(400, JSON.stringify({ type: 'error', code: 'bad_image', message: 'not a PNG' }));
  assert.deepEqual(r.notice.lines, ['not added: not a PNG [bad_image]']);

  // Not the daemon's JSON: said plainly, as an error of code "http".
  r = readUploadAnswer(404, '');
  assert.equal(r.answer.code, 'http');
  assert.match(r.notice.lines[0], /HTTP 404: this daemon cannot add puppets/);
  r = readUploadAnswer(502, '<html>Bad Gateway</html>');
  assert.match(r.answer.message, /HTTP 502: <html>Bad Gateway/);
  r = readUploadAnswer(0, '');
  assert.match(r.answer.message, /no answer from the daemon/);
  r = readUploadAnswer(200, '{"type":"something_else"}');
  assert.equal(r.notice.kind, 'error', 'a 200 that is not puppet_added did not add anything');
  r = readUploadAnswer(200, '[1, 2]');
  assert.equal(r.answer.type, 'error');
});

test('the tests\' PNGs: written, then read back as the mock reads uploads', () => {
  const cutOut = encodePng(30, 20, (x) => (x < 10 ? [0, 0, 0, 0] : [200, 30, 30, 255]));
  assert.deepEqual(describePng(cutOut), { width: 30, height: 20, opaque: false });
  const opaque = encodePng(200, 100, () => [20, 150, 160, 255]);
  assert.deepEqual(describePng(opaque), { width: 200, height: 100, opaque: true });
  // One pixel short of opaque, at the very end.
  const almost = encodePng(5, 5, (x, y) => [1, 2, 3, x === 4 && y === 4 ? 254 : 255]);
  assert.equal(describePng(almost).opaque, false);
  assert.match(describePng(Buffer.from('This is a text file.\n')).error, /not a PNG/);
  assert.match(describePng(cutOut.subarray(0, 40)).error, /cut short|no image data/);
  const corrupt = Buffer.from(opaque);
  corrupt.fill(0, 41, 60); // inside the image data
  assert.ok(describePng(corrupt).error);
});

// The stage's pointers without a browser: an element that keeps its
// listeners, and pointer events with a capturing target.
function fakeStage() {
  const listeners = {};
  const captured = new Set();
  const element = {
    addEventListener: (name, f) => { listeners[name] = f; },
    setPointerCapture: (id) => captured.add(id),
  };
  const fire = (name, pointerId, extra = {}) => listeners[name]({
    pointerId, pointerType: 'touch', button: 0, clientX: 10, clientY: 20, currentTarget: element, ...extra,
  });
  return { element, fire, captured };
}

test('a brush stroke or a contact holds the stage until its lift; a lost connection lets go', () => {
  const { element, fire, captured } = fakeStage();
  const view = { clientToStage: (x, y) => [x, y] };
  let brushOn = false;
  const brush = { pointerDown: () => brushOn };
  let lifts = 0;
  const contacts = new PointerContacts(element, view, { canStart: () => true, tools: [brush], onLifted: () => { lifts += 1; } });
  assert.equal(contacts.held(), 0);

  brushOn = true;
  fire('pointerdown', 1);
  assert.equal(contacts.held(), 1, 'the stroke holds the stage');
  assert.ok(captured.has(1), 'the stroke\'s lift reaches the stage wherever it happens');
  assert.equal(contacts.takeMessage(), null, 'a stroke is not a contact');
  brushOn = false;
  fire('pointerdown', 2);
  assert.equal(contacts.held(), 2, 'a contact as well');
  fire('pointerup', 1);
  assert.equal(contacts.held(), 1);
  assert.equal(lifts, 1, 'the stroke\'s lift is told');
  fire('pointercancel', 2);
  assert.equal(contacts.held(), 0);
  assert.equal(lifts, 2);
  fire('pointerup', 2);
  assert.equal(lifts, 2, 'a second lift of the same pointer is not');

  brushOn = true;
  fire('pointerdown', 3);
  assert.equal(contacts.held(), 1);
  contacts.reset();
  assert.equal(contacts.held(), 0, 'a lost connection lets go');
});

// Issue 31: the keyframe stage's names overlapped ("wave leftwave right").
test('key pad names overlap neither each other nor a dot, and stay on the pad', () => {
  const size = 180;
  const keys = [['rest', [0.5, 0.5]], ['wave left', [0.15, 0.85]], ['wave right', [0.85, 0.85]],
    ['crouch', [0.5, 0.1]], ['lean left', [0.1, 0.3]], ['lean right', [0.9, 0.3]],
    ['a very long key name indeed', [0.5, 0.8]], ['close', [0.52, 0.52]]];
  const dots = keys.map(([, [u, v]]) => [u * size, (1 - v) * size]);
  const measure = (t) => 6 * t.length; // about 11 px system-ui
  const labels = keyLabelLayout(dots, keys.map(([n]) => n), size, measure);
  assert.equal(labels.length, keys.length);
  const cover = (a, b) => Math.max(0, Math.min(a.x + a.w, b.x + b.w) - Math.max(a.x, b.x))
    * Math.max(0, Math.min(a.y + a.h, b.y + b.h) - Math.max(a.y, b.y));
  labels.forEach((a, i) => {
    assert.ok(a.x >= 0 && a.y >= 0 && a.x + a.w <= size && a.y + a.h <= size, `${a.text} on the pad`);
    assert.ok(a.w <= measure(a.text) + 1e-9, `${a.text} drawn in its box`);
    labels.slice(i + 1).forEach((b) => assert.equal(cover(a, b), 0, `${a.text} / ${b.text}`));
    dots.forEach(([x, y], j) => assert.equal(cover(a, { x: x - 6, y: y - 6, w: 12, h: 12 }), 0, `${a.text} on dot ${j}`));
  });
  // The six of the demo keys keep their whole names.
  labels.slice(0, 6).forEach((l, i) => assert.equal(l.text, keys[i][0]));
});
