// A stand-in for `puppetry serve`, to develop and test clients/web without the
// daemon: serves the page and a generated texture, and speaks docs/protocol.md
// with one quad puppet that follows the first contact that grabs it.
// It also checks what the page sends and answers violations with "error".
//
//   PORT=8080 MOCK_TOKEN=T node mock-server.mjs   (PORT 0 or unset: any free port)
// Prints one JSON line {"url": …} when listening.

import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import zlib from 'node:zlib';
import { fileURLToPath } from 'node:url';
import { WebSocketServer } from 'ws';

const WEB = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../../clients/web');
const TOKEN = process.env.MOCK_TOKEN ?? 'T';
const started = process.hrtime.bigint();
const STAGE = { width: 800, height: 600 };
// Quad corners in stage coordinates (y-up): bottom-left, bottom-right, top-right, top-left.
const REST = [300, 200, 500, 200, 500, 400, 300, 400];
const UV = [0, 1, 1, 1, 1, 0, 0, 0]; // v down from the top of the picture
const TRIANGLES = [0, 1, 2, 0, 2, 3];

// ---------------------------------------------------------------- texture

const CRC = Array.from({ length: 256 }, (_, n) => {
  let c = n;
  for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
  return c >>> 0;
});
const crc32 = (buf) => {
  let c = 0xffffffff;
  for (const b of buf) c = CRC[(c ^ b) & 0xff] ^ (c >>> 8);
  return (c ^ 0xffffffff) >>> 0;
};
function chunk(type, data) {
  const out = Buffer.alloc(12 + data.length);
  out.writeUInt32BE(data.length, 0);
  out.write(type, 4, 'latin1');
  data.copy(out, 8);
  out.writeUInt32BE(crc32(out.subarray(4, 8 + data.length)), 8 + data.length);
  return out;
}
// Quadrants red (top left), green, blue, yellow, so a flipped or mirrored
// texture is obvious in a screenshot.
function texturePng(size = 64) {
  const raw = Buffer.alloc(size * (1 + 4 * size));
  for (let y = 0; y < size; y++) {
    const row = y * (1 + 4 * size); // filter byte 0, then RGBA
    for (let x = 0; x < size; x++) {
      const q = (y < size / 2 ? 0 : 2) + (x < size / 2 ? 0 : 1);
      const border = x < 3 || y < 3 || x >= size - 3 || y >= size - 3;
      const rgb = border ? [0, 0, 0] : [[230, 40, 40], [40, 180, 60], [40, 80, 230], [240, 210, 30]][q];
      raw.set([...rgb, 255], row + 1 + 4 * x);
    }
  }
  const ihdr = Buffer.alloc(13);
  ihdr.writeUInt32BE(size, 0);
  ihdr.writeUInt32BE(size, 4);
  ihdr.set([8, 6, 0, 0, 0], 8); // 8-bit RGBA
  return Buffer.concat([
    Buffer.from([137, 80, 78, 71, 13, 10, 26, 10]),
    chunk('IHDR', ihdr), chunk('IDAT', zlib.deflateSync(raw)), chunk('IEND', Buffer.alloc(0)),
  ]);
}
const TEXTURE = texturePng();

// ---------------------------------------------------------------- HTTP

const TYPES = { '.html': 'text/html', '.js': 'text/javascript', '.css': 'text/css' };
const server = http.createServer((req, res) => {
  const url = new URL(req.url, 'http://x');
  if (url.pathname === '/puppets/0/texture.png') {
    res.writeHead(200, { 'content-type': 'image/png' });
    return res.end(TEXTURE);
  }
  const name = url.pathname === '/' ? 'index.html' : url.pathname.slice(1);
  const file = path.join(WEB, name);
  if (name.includes('/') || !TYPES[path.extname(name)] || !fs.existsSync(file)) {
    res.writeHead(404);
    return res.end();
  }
  res.writeHead(200, { 'content-type': TYPES[path.extname(name)], 'cache-control': 'no-store' });
  res.end(fs.readFileSync(file));
});

// ---------------------------------------------------------------- stream

let positions = REST.slice();
let sequence = 0;
let nextClient = 1;
let nextHandle = 1;
let grab = null; // {client, contact, handle, from: [x, y], start: positions}
let pins = [];   // {id, owner, kind: 'pin', at}
const clients = new Set();

const handles = () => [...(grab ? [grab.handle] : []), ...pins];
const broadcast = (data) => { for (const c of clients) if (c.ready) c.ws.send(data); };
const sendHandles = () => broadcast(JSON.stringify({ type: 'handles', puppet: 0, handles: handles() }));
const inside = (x, y) => {
  const xs = positions.filter((_, i) => i % 2 === 0);
  const ys = positions.filter((_, i) => i % 2 === 1);
  return x >= Math.min(...xs) && x <= Math.max(...xs) && y >= Math.min(...ys) && y <= Math.max(...ys);
};

function sendFrame() {
  const n = positions.length / 2;
  const buf = Buffer.alloc(32 + 8 * n);
  buf.writeUInt32LE(1, 0);
  buf.writeUInt32LE(0, 4);
  buf.writeBigUInt64LE(BigInt(++sequence), 8);
  buf.writeDoubleLE(Number(process.hrtime.bigint() - started) / 1e9, 16);
  buf.writeUInt32LE(n, 24);
  positions.forEach((v, i) => buf.writeFloatLE(v, 32 + 4 * i));
  broadcast(buf);
}

const finite = (v) => typeof v === 'number' && Number.isFinite(v);

// Returns an error message, or null when the input was fine.
function onInput(c, msg) {
  // The page asks for the takes on connecting; the mock has none.
  if (msg.type === 'list_takes') {
    c.ws.send(JSON.stringify({ type: 'takes', takes: [] }));
    return null;
  }
  if (c.role !== 'performer') return 'only performers may send input';
  if (msg.type === 'contacts') {
    if (!Array.isArray(msg.contacts)) return 'contacts: not an array';
    const seen = new Set();
    for (const e of msg.contacts) {
      if (!Number.isInteger(e?.id) || e.id < 0) return 'contacts: bad id';
      if (seen.has(e.id)) return `contacts: id ${e.id} twice in one frame`;
      seen.add(e.id);
      if (e.phase === 'down') {
        if (c.down.has(e.id)) return `contacts: id ${e.id} down twice`;
        if (!finite(e.x) || !finite(e.y)) return 'contacts: bad point';
        c.down.add(e.id);
        if (!grab && inside(e.x, e.y)) {
          const handle = { id: nextHandle++, owner: `client:${c.id}`, kind: 'contact', at: [e.x, e.y] };
          grab = { client: c, contact: e.id, handle, from: [e.x, e.y], start: positions.slice() };
          sendHandles();
        }
      } else if (e.phase === 'move') {
        if (!c.down.has(e.id)) return `contacts: move of id ${e.id} that is not down`;
        if (!finite(e.x) || !finite(e.y)) return 'contacts: bad point';
        if (grab?.client === c && grab.contact === e.id) {
          const [dx, dy] = [e.x - grab.from[0], e.y - grab.from[1]];
          positions = grab.start.map((v, i) => v + (i % 2 ? dy : dx));
          sendFrame();
        }
      } else if (e.phase === 'up') {
        if (!c.down.delete(e.id)) return `contacts: up of id ${e.id} that is not down`;
        if (grab?.client === c && grab.contact === e.id) { grab = null; sendHandles(); }
      } else {
        return 'contacts: bad phase';
      }
    }
    return null;
  }
  if (msg.type === 'pin') {
    if (!finite(msg.x) || !finite(msg.y)) return 'pin: bad point';
    if (!inside(msg.x, msg.y)) return null; // empty stage: nothing to pin
    pins.push({ id: nextHandle++, owner: `client:${c.id}`, kind: 'pin', at: [msg.x, msg.y] });
    sendHandles();
    return null;
  }
  if (msg.type === 'unpin') {
    if (msg.puppet !== 0 || !pins.some((p) => p.id === msg.handle)) return 'unpin: no such pin';
    pins = pins.filter((p) => p.id !== msg.handle);
    sendHandles();
    return null;
  }
  return `unknown message type ${JSON.stringify(msg.type)}`;
}

const wss = new WebSocketServer({ server, path: '/ws', maxPayload: 64 * 1024 });
wss.on('connection', (ws) => {
  const c = { ws, id: nextClient++, role: null, ready: false, down: new Set() };
  const fail = (message, close = false) => {
    ws.send(JSON.stringify({ type: 'error', message }));
    if (close) ws.close();
  };
  ws.on('message', (data, isBinary) => {
    let msg;
    try {
      msg = isBinary ? null : JSON.parse(data.toString());
    } catch { /* handled below */ }
    if (!msg || typeof msg !== 'object') return fail('malformed message', !c.ready);
    if (!c.ready) {
      if (msg.type !== 'hello') return fail('expected hello', true);
      if (msg.role === 'performer' && msg.token !== TOKEN) return fail('wrong token', true);
      if (msg.role !== 'performer' && msg.role !== 'viewer') return fail('bad role', true);
      c.role = msg.role;
      c.ready = true;
      clients.add(c);
      ws.send(JSON.stringify({
        type: 'stage', client: c.id, role: c.role, stage: STAGE,
        puppets: [{ id: 0, name: 'quad', texture: '/puppets/0/texture.png',
          rest: REST, uv: UV, triangles: TRIANGLES, handles: handles() }],
      }));
      if (positions.some((v, i) => v !== REST[i])) sendFrame(); // show the current pose
      return;
    }
    const err = onInput(c, msg);
    if (err) {
      console.error(`mock: client ${c.id}: ${err}`);
      fail(err);
    }
  });
  ws.on('close', () => {
    clients.delete(c);
    if (grab?.client === c) { grab = null; sendHandles(); }
  });
});

server.listen(Number(process.env.PORT ?? 0), '127.0.0.1', () => {
  console.log(JSON.stringify({ url: `http://127.0.0.1:${server.address().port}/` }));
});
