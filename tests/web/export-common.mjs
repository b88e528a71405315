// What the export checks share: a tiny static file server on 127.0.0.1
// (port 0: any free port; no network elsewhere), headless Chromium with a
// fresh profile, and a hard deadline so a hang fails instead of waiting.

import fs from 'node:fs';
import http from 'node:http';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { removeProfile } from './profile.mjs';

export const HERE = path.dirname(fileURLToPath(import.meta.url));
export const ROOT = path.resolve(HERE, '../..');

const TYPES = {
  '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript', '.css': 'text/css',
  '.png': 'image/png', '.glb': 'model/gltf-binary', '.json': 'application/json',
};

/**
 * Serves `routes`: an object from URL path prefix ("/three/") to a folder,
 * or from an exact path ("/") to {body, type}. Resolves to {server, url}.
 */
export function serve(routes, onUpgrade) {
  const server = http.createServer((req, res) => {
    const url = new URL(req.url, 'http://x');
    const exact = routes[url.pathname];
    if (exact && typeof exact === 'object') {
      res.writeHead(200, { 'content-type': exact.type, 'cache-control': 'no-store' });
      return res.end(exact.body);
    }
    for (const [prefix, target] of Object.entries(routes)) {
      if (typeof target !== 'string' || !url.pathname.startsWith(prefix)) continue;
      const rel = decodeURIComponent(url.pathname.slice(prefix.length));
      const file = path.resolve(target, rel);
      if (!file.startsWith(path.resolve(target)) || !fs.existsSync(file) || !fs.statSync(file).isFile()) break;
      res.writeHead(200, { 'content-type': TYPES[path.extname(file)] ?? 'application/octet-stream', 'cache-control': 'no-store' });
      return res.end(fs.readFileSync(file));
    }
    res.writeHead(404);
    res.end();
  });
  if (onUpgrade) onUpgrade(server);
  return new Promise((resolve) => {
    server.listen(0, '127.0.0.1', () => resolve({ server, url: `http://127.0.0.1:${server.address().port}` }));
  });
}

/**
 * Headless Chromium (CHROMIUM or /usr/bin/chromium) with a fresh
 * --user-data-dir; `webgl` adds SwiftShader so WebGL works without a GPU.
 * Resolves to {context, page, close}.
 */
export async function launch({ width = 800, height = 600, webgl = false } = {}) {
  const { chromium } = await import('playwright-core');
  const executablePath = process.env.CHROMIUM ?? '/usr/bin/chromium';
  if (!fs.existsSync(executablePath)) {
    throw new Error(`Chromium not found at ${executablePath}: install it (Debian: apt-get install chromium) or set CHROMIUM`);
  }
  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'puppetry-export-chromium-'));
  const args = [
    '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
    '--disable-background-networking', '--disable-component-update', '--disable-sync',
  ];
  if (webgl) args.push('--use-gl=angle', '--use-angle=swiftshader', '--enable-unsafe-swiftshader');
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath, headless: true, timeout: 30_000, args,
    viewport: { width, height }, deviceScaleFactor: 1,
  });
  const page = context.pages()[0] ?? await context.newPage();
  page.setDefaultTimeout(30_000);
  const errors = [];
  page.on('pageerror', (err) => errors.push(`pageerror: ${err.message}`));
  page.on('console', (msg) => { if (msg.type() === 'error') errors.push(`console: ${msg.text()}`); });
  const close = async () => {
    await context.close().catch(() => {});
    removeProfile(userDataDir, {});
  };
  return { context, page, errors, close };
}

/** Runs `main`, prints its result as one JSON line, exits 0; on failure or after `ms`, prints {ok: false, reason} and exits 1. */
export function run(main, ms = 100_000) {
  const fail = (reason) => {
    console.log(JSON.stringify({ ok: false, reason }));
    process.exit(1);
  };
  const watchdog = setTimeout(() => fail(`timed out after ${ms} ms`), ms);
  main().then(
    (result) => {
      clearTimeout(watchdog);
      process.stdout.write(`${JSON.stringify({ ok: true, ...result })}\n`, () => process.exit(0));
    },
    (err) => fail(err?.stack ?? String(err)),
  );
}
