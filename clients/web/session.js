// What the page's address asks for, read once at load: the view (the
// performer's page, or `?view=show`, only the puppets for a projector or
// OBS's browser source), and the role and token to say hello with. The
// token is moved out of the address bar at once (into sessionStorage, so a
// reload in the same tab still has it) and only ever sent in the hello.
// No DOM here beyond what is passed in, so tests run it in Node.

import { ROLE } from './protocol.js';

/** sessionStorage key of the token taken from the address. */
export const TOKEN_KEY = 'puppetry.token';

/**
 * The view `params` (URLSearchParams) asks for:
 *   show         `view=show`: only the puppets, full window, no UI
 *   transparent  `background=transparent`: a transparent page and canvas
 *   size         `size=WxH`: the drawing buffer's fixed size, or null (the window's)
 *   dots         handle dots and cursors: always on the performer's page, `dots=1` in the show view
 */
export function viewOptions(params) {
  const show = params.get('view') === 'show';
  return {
    show,
    transparent: params.get('background') === 'transparent',
    size: parseSize(params.get('size')),
    dots: !show || params.get('dots') === '1',
  };
}

/** "1920x1080" as {width, height}; null unless both are whole numbers from 1 to 16384. */
export function parseSize(text) {
  const m = /^(\d{1,5})[x×](\d{1,5})$/.exec(text ?? '');
  if (!m) return null;
  const [width, height] = [Number(m[1]), Number(m[2])];
  const ok = (v) => v >= 1 && v <= 16384;
  return ok(width) && ok(height) ? { width, height } : null;
}

/**
 * The role to ask for and the token to ask with, from the address
 * (`role=performer&token=…` or `role=director&token=…`) or, after a reload,
 * from `storage` (sessionStorage). A token in the address is stored and the
 * address rewritten without it (`replaceUrl(url)`: history.replaceState);
 * the role stays in the address so a reload asks again. The show view is
 * always a viewer. Returns {role, token} (token '' when there is none).
 */
export function takeAccess(location, storage, replaceUrl, { show = false } = {}) {
  const url = new URL(location.href);
  const params = url.searchParams;
  const asked = params.get('role');
  const role = show ? ROLE.VIEWER : asked === ROLE.PERFORMER || asked === ROLE.DIRECTOR ? asked : ROLE.VIEWER;
  if (params.has('token')) {
    const fromUrl = params.get('token') ?? '';
    params.delete('token');
    replaceUrl(url.toString());
    if (fromUrl) safely(() => storage.setItem(TOKEN_KEY, fromUrl));
    if (role !== ROLE.VIEWER) return { role, token: fromUrl };
  }
  const stored = role === ROLE.VIEWER ? '' : safely(() => storage.getItem(TOKEN_KEY)) ?? '';
  return { role, token: stored };
}

/** Forgets the stored token (the server refused it: a reload must not send it again). */
export function forgetToken(storage) {
  safely(() => storage.removeItem(TOKEN_KEY));
}

// Storage throws when the browser refuses it (some private modes): the page
// then only loses the token across reloads.
function safely(f) {
  try {
    return f();
  } catch {
    return undefined;
  }
}
