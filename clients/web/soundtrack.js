// A soundtrack the page plays while a take records or plays, in time with
// the take, so a performer hears what they perform to. The sound file
// stays on this machine (picked with the toolbar's ♪); `puppetry export
// --audio` puts the same file in the video, from the take's start.
//
// The take's time is the daemon's: the `take` message says, in the
// daemon's clock, when it was sent and how far the take recording (or
// playing) was then; the page knows the daemon's clock from its pings
// (`pong` carries it; the round trip with the shortest time is trusted,
// its half taken as the way there). So a page that joins a take halfway
// plays from halfway, and a page whose audio drifts is put back.

/** The daemon's clock as this page reckons it, from `pong`s. */
export class DaemonClock {
  constructor() {
    this.offset = null;   // daemon seconds minus page seconds
    this.bestRtt = Infinity;
    this.samples = 0;
  }

  /** A `pong`: `sent` and `now` are the page's ms (performance.now()), `clock` the daemon's s. */
  onPong(sent, now, clock) {
    const rtt = now - sent;
    if (!(rtt >= 0) || typeof clock !== 'number') return;
    // Older estimates age: a round trip counts a little worse each time,
    // so a clock that drifts is followed.
    this.bestRtt += 2;
    if (rtt <= this.bestRtt) {
      this.bestRtt = rtt;
      this.offset = clock - (sent + rtt / 2) / 1000;
    }
    this.samples += 1;
  }

  /** A daemon time heard now without a round trip (a `take` message): a first guess. */
  guess(clock) {
    if (this.offset === null && typeof clock === 'number') this.offset = clock - performance.now() / 1000;
  }

  /** The daemon's clock now (seconds), or null before anything was heard. */
  now() {
    return this.offset === null ? null : performance.now() / 1000 + this.offset;
  }
}

/** How far the sound may drift from the take before it is put back (s). */
const DRIFT = 0.04;
/** The most the sound is started ahead of the take, to make up for the time a seek takes (s). */
const MAX_LEAD = 0.5;
/** How often a playing sound is compared with the take (ms). */
const CHECK_MS = 500;

export class Soundtrack {
  /** elements: {file (an input type=file), name (where its name shows)}; clock: a DaemonClock. */
  constructor(elements, clock) {
    this.elements = elements;
    this.clock = clock;
    this.audio = new Audio();
    this.audio.preload = 'auto';
    this.take = null;
    this.url = null;
    this.timer = null;
    // How far ahead of the take a seek lands, learnt from how far behind
    // the sound was after the last ones (a seek and a start take time).
    this.lead = 0;
    this.seeked = false;
    elements.file.addEventListener('change', () => this.load(elements.file.files?.[0] ?? null));
  }

  /** Plays `file` (a File or Blob) from now on; null: none. */
  load(file) {
    if (this.url) URL.revokeObjectURL(this.url);
    this.url = file ? URL.createObjectURL(file) : null;
    this.audio.pause();
    if (this.url) this.audio.src = this.url;
    else this.audio.removeAttribute('src');
    this.elements.name.textContent = file?.name ?? '';
    this.follow();
  }

  /** A `take` message. */
  onTake(msg) {
    this.take = msg;
    this.clock.guess(msg.clock);
    this.follow();
  }

  /** Seconds into the take recording or playing now, or null when none is. */
  position() {
    const t = this.take;
    if (!t || (!t.recording && typeof t.played !== 'number')) return null;
    const now = this.clock.now() ?? t.clock;
    const since = t.recording ? t.elapsed : t.played;
    return Math.max(0, since + (now - t.clock));
  }

  /** Starts, stops or moves the sound to where the take is. */
  follow() {
    clearTimeout(this.timer);
    const at = this.url ? this.position() : null;
    if (at === null) {
      if (!this.audio.paused) this.audio.pause();
      if (this.url && this.audio.currentTime !== 0) this.audio.currentTime = 0;
      this.seeked = false;
      return;
    }
    const behind = at - this.audio.currentTime;
    if (Math.abs(behind) > DRIFT) {
      // Still behind after a seek: seek further ahead next time.
      if (this.seeked && !this.audio.paused) this.lead = Math.min(MAX_LEAD, Math.max(0, this.lead + behind));
      this.audio.currentTime = at + this.lead;
      this.seeked = true;
    }
    if (this.audio.paused) this.audio.play().catch(() => {});
    this.timer = setTimeout(() => this.follow(), CHECK_MS);
  }

  /** What the page shows of it: {loaded, playing, at, expected}. */
  state() {
    return {
      loaded: this.url !== null,
      playing: !this.audio.paused,
      at: this.audio.currentTime,
      expected: this.position(),
    };
  }
}
