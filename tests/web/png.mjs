// PNG in and out for the page tests, with nothing but node:zlib: a writer
// for the test pictures (the mock's texture, the figures puppets.mjs
// uploads), and the small reader mock-server.mjs checks uploads with, as
// the daemon would: is it a PNG at all, how large, and is every pixel
// opaque (then the daemon can only mesh the whole rectangle).

import zlib from 'node:zlib';

const SIGNATURE = Buffer.from([137, 80, 78, 71, 13, 10, 26, 10]);

const CRC = Array.from({ length: 256 }, (_, n) => {
  let c = n;
  for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
  return c >>> 0;
});

function crc32(buf) {
  let c = 0xffffffff;
  for (const b of buf) c = CRC[(c ^ b) & 0xff] ^ (c >>> 8);
  return (c ^ 0xffffffff) >>> 0;
}

function chunk(type, data) {
  const out = Buffer.alloc(12 + data.length);
  out.writeUInt32BE(data.length, 0);
  out.write(type, 4, 'latin1');
  data.copy(out, 8);
  out.writeUInt32BE(crc32(out.subarray(4, 8 + data.length)), 8 + data.length);
  return out;
}

/** An 8-bit RGBA PNG of `width` × `height` whose pixel (x, y), y down from the top, is pixel(x, y) → [r, g, b, a]. */
export function encodePng(width, height, pixel) {
  const stride = 1 + 4 * width; // filter byte 0, then RGBA
  const raw = Buffer.alloc(height * stride);
  for (let y = 0; y < height; y++) {
    for (let x = 0; x < width; x++) raw.set(pixel(x, y), y * stride + 1 + 4 * x);
  }
  const ihdr = Buffer.alloc(13);
  ihdr.writeUInt32BE(width, 0);
  ihdr.writeUInt32BE(height, 4);
  ihdr.set([8, 6, 0, 0, 0], 8); // 8-bit RGBA, not interlaced
  return Buffer.concat([SIGNATURE, chunk('IHDR', ihdr), chunk('IDAT', zlib.deflateSync(raw)), chunk('IEND', Buffer.alloc(0))]);
}

// Channels per pixel of each PNG colour type.
const CHANNELS = { 0: 1, 2: 3, 3: 1, 4: 2, 6: 4 };

/**
 * What a PNG is: {width, height, opaque} or {error} saying why it is not
 * one. `opaque` is true when every pixel is, false when some pixel is not,
 * null when this reader cannot tell (a palette with transparency, an
 * interlaced picture).
 */
export function describePng(buf) {
  if (buf.length < 8 || !buf.subarray(0, 8).equals(SIGNATURE)) return { error: 'not a PNG file (no PNG signature)' };
  let at = 8;
  let header = null;
  let transparency = false;
  const data = [];
  while (at + 8 <= buf.length) {
    const length = buf.readUInt32BE(at);
    const type = buf.toString('latin1', at + 4, at + 8);
    const body = buf.subarray(at + 8, at + 8 + length);
    if (body.length !== length) return { error: `the PNG is cut short (in its ${type} chunk)` };
    if (!header) {
      if (type !== 'IHDR' || length !== 13) return { error: 'the PNG has no header (IHDR) first' };
      header = {
        width: body.readUInt32BE(0), height: body.readUInt32BE(4),
        depth: body[8], colour: body[9], interlaced: body[12] !== 0,
      };
    }
    if (type === 'tRNS') transparency = true;
    if (type === 'IDAT') data.push(body);
    if (type === 'IEND') break;
    at += 12 + length;
  }
  if (!header) return { error: 'the PNG is cut short (no header)' };
  const { width, height, depth, colour, interlaced } = header;
  if (!width || !height) return { error: `the PNG is ${width}×${height} pixels` };
  const depths = colour === 0 ? [1, 2, 4, 8, 16] : colour === 3 ? [1, 2, 4, 8] : [8, 16];
  if (!CHANNELS[colour] || !depths.includes(depth)) return { error: `the PNG's colour type ${colour} at depth ${depth} is not valid` };
  if (!data.length) return { error: 'the PNG has no image data' };
  let raw;
  try {
    raw = zlib.inflateSync(Buffer.concat(data));
  } catch {
    return { error: 'the PNG\'s image data is corrupt' };
  }
  const size = { width, height };
  if (interlaced) return { ...size, opaque: null };
  const stride = Math.ceil((width * CHANNELS[colour] * depth) / 8);
  if (raw.length < height * (1 + stride)) return { error: 'the PNG\'s image data is shorter than its size says' };
  // Grey and colour without a tRNS chunk have no transparency at all.
  if (colour === 0 || colour === 2 || colour === 3) return { ...size, opaque: transparency ? null : true };
  const pixels = unfilter(raw, height, stride, (CHANNELS[colour] * depth) / 8);
  if (!pixels) return { error: 'the PNG\'s image data has an unknown filter' };
  // Alpha is each pixel's last channel: 1 byte at depth 8, 2 at 16.
  const bytes = depth / 8;
  const pixelBytes = CHANNELS[colour] * bytes;
  for (let y = 0; y < height; y++) {
    for (let x = 0; x < width; x++) {
      const alpha = y * stride + (x + 1) * pixelBytes - bytes;
      for (let k = 0; k < bytes; k++) if (pixels[alpha + k] !== 255) return { ...size, opaque: false };
    }
  }
  return { ...size, opaque: true };
}

// The scanlines of non-interlaced image data without their filters; null
// for a filter type PNG does not have.
function unfilter(raw, height, stride, bpp) {
  const out = Buffer.alloc(height * stride);
  for (let y = 0; y < height; y++) {
    const filter = raw[y * (stride + 1)];
    const line = raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    const row = y * stride;
    for (let i = 0; i < stride; i++) {
      const a = i >= bpp ? out[row + i - bpp] : 0;
      const b = y ? out[row - stride + i] : 0;
      const c = i >= bpp && y ? out[row - stride + i - bpp] : 0;
      let predicted;
      if (filter === 0) predicted = 0;
      else if (filter === 1) predicted = a;
      else if (filter === 2) predicted = b;
      else if (filter === 3) predicted = (a + b) >> 1;
      else if (filter === 4) predicted = paeth(a, b, c);
      else return null;
      out[row + i] = (line[i] + predicted) & 255;
    }
  }
  return out;
}

function paeth(a, b, c) {
  const p = a + b - c;
  const [pa, pb, pc] = [Math.abs(p - a), Math.abs(p - b), Math.abs(p - c)];
  return pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
}
