// The page's own chrome around the stage: the connection indicator (a dot
// in the toolbar, and a red banner over everything while disconnected, so
// nobody performs into a dead page), the latency (ping/pong round trip,
// median of the last few) and drawing rate readout, the fullscreen button,
// and hiding the toolbar (its button and the `h` key) so a projected stage
// shows nothing but the puppets.

/** The median of `values` (numbers); null when there are none. */
export function median(values) {
  if (!values.length) return null;
  const s = [...values].sort((a, b) => a - b);
  const mid = s.length >> 1;
  return s.length % 2 ? s[mid] : (s[mid - 1] + s[mid]) / 2;
}

/**
 * Round trips of the last `keep` pings: one slow answer (a garbage
 * collection, a busy stage thread) does not make the readout jump.
 */
export class LatencyMeter {
  constructor(keep = 5) {
    this.keep = keep;
    this.samples = [];
  }

  add(ms) {
    if (!Number.isFinite(ms) || ms < 0) return;
    this.samples.push(ms);
    if (this.samples.length > this.keep) this.samples.shift();
  }

  clear() {
    this.samples = [];
  }

  /** Milliseconds, or null before the first pong. */
  get ms() {
    return median(this.samples);
  }
}

/** Animation frames per second, counted over the last whole second. */
export class FpsMeter {
  constructor() {
    this.since = null;
    this.count = 0;
    this.fps = null;
  }

  /** Called once per animation frame with its timestamp (ms); true when the rate was updated. */
  tick(now) {
    // Frames after `since` (the frame at `since` closed the last count).
    if (this.since === null) {
      this.since = now;
      return false;
    }
    this.count++;
    if (now - this.since < 1000) return false;
    this.fps = Math.round((1000 * this.count) / (now - this.since));
    this.since = now;
    this.count = 0;
    return true;
  }
}

export class Hud {
  /**
   * elements: {bar, connection, banner, bannerText, bannerClose, readout,
   * hideBar, showBar, fullscreen}; onLayout(): the space left to the
   * stage changed. `chrome` lists other elements that hide with the bar.
   * keys: whether `h` and `f` work (not in the show view, which has no UI).
   */
  constructor(elements, { onLayout, chrome = [], keys = true }) {
    this.el = elements;
    this.onLayout = onLayout;
    this.chrome = chrome;
    this.barHidden = false;
    this.notice = null; // a lasting banner ({text, kind}) shown while connected
    this.el.hideBar.addEventListener('click', () => this.setBarHidden(true));
    this.el.showBar.addEventListener('click', () => this.setBarHidden(false));
    this.el.bannerClose.addEventListener('click', () => {
      this.notice = null;
      this.el.banner.hidden = true;
    });
    addEventListener('keydown', (e) => {
      if (!keys) return;
      if (e.repeat || e.ctrlKey || e.metaKey || e.altKey) return;
      if (e.target instanceof HTMLElement && e.target.matches('input, select, textarea')) return;
      if (e.key === 'h' || e.key === 'H') this.setBarHidden(!this.barHidden);
      else if (e.key === 'f' || e.key === 'F') this.toggleFullscreen();
    });
    const fs = this.el.fullscreen;
    fs.hidden = !document.fullscreenEnabled;
    fs.addEventListener('click', () => this.toggleFullscreen());
    document.addEventListener('fullscreenchange', () => {
      fs.setAttribute('aria-pressed', String(!!document.fullscreenElement));
      // Symbols only, the words in the title: the toolbar's room is short.
      fs.textContent = document.fullscreenElement ? '⤡' : '⤢';
      fs.title = document.fullscreenElement ? 'Exit fullscreen (f)' : 'Fullscreen (f)';
    });
    // The bar wraps when the window narrows or tools appear: the stage
    // below it must move.
    new ResizeObserver(() => this.onLayout()).observe(this.el.bar);
  }

  toggleFullscreen() {
    if (!document.fullscreenEnabled) return;
    if (document.fullscreenElement) document.exitFullscreen().catch(() => {});
    else document.documentElement.requestFullscreen().catch(() => {});
  }

  setBarHidden(hidden) {
    this.barHidden = hidden;
    this.el.bar.hidden = hidden;
    this.el.showBar.hidden = !hidden;
    document.body.classList.toggle('bar-hidden', hidden);
    for (const e of this.chrome) e.classList.toggle('chrome-hidden', hidden);
    this.onLayout();
  }

  /** The height the bar takes from the top of the window (0 when hidden). */
  barHeight() {
    return this.barHidden ? 0 : this.el.bar.getBoundingClientRect().height;
  }

  /**
   * The connection: `connected` (true/false) and what to say. Disconnected
   * is loud (`loud`, but for the first connection of the page): the red
   * banner, whatever else is hidden.
   */
  setConnection(connected, text, { loud = true } = {}) {
    const c = this.el.connection;
    c.classList.toggle('up', connected);
    c.classList.toggle('down', !connected);
    c.title = text;
    c.textContent = connected ? '● live' : '● offline';
    if (!connected && loud) this.showBanner(text, 'down');
    else if (this.notice) this.showBanner(this.notice.text, this.notice.kind);
    else this.el.banner.hidden = true;
  }

  /** A banner that stays (until closed) even when connected: `kind` "notice". */
  setNotice(text, kind = 'notice') {
    this.notice = text ? { text, kind } : null;
    if (this.notice) this.showBanner(text, kind);
  }

  showBanner(text, kind) {
    const b = this.el.banner;
    b.hidden = false;
    b.dataset.kind = kind;
    this.el.bannerText.textContent = text;
    this.el.bannerClose.hidden = kind === 'down';
  }

  /** The readout: round trip (ms, or null) and frames per second (or null). */
  setReadout(ms, fps) {
    const parts = [];
    parts.push(ms === null ? 'rtt –' : `rtt ${ms < 10 ? ms.toFixed(1) : Math.round(ms)} ms`);
    parts.push(fps === null ? '– fps' : `${fps} fps`);
    this.el.readout.textContent = parts.join(' · ');
  }
}
