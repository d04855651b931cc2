// The replay bar's logic, shared by the learner's debrief and the faculty review (both open
// debrief.html): playback speeds and pacing, where the event ticks sit along the bar, how each
// kind of event is drawn, what to announce at a step, and a frame loader that keeps at most one
// frame request in flight. Pure: no DOM, no timers, no fetch (the page passes its own).

/** Playback speeds offered, as multipliers of the base pace. Simulator choice: half speed to
 * read each event slowly, up to four times to skim a log of 40 to 200 commands; beyond those
 * the frames' own rendering time sets the pace anyway. */
export const SPEEDS = [0.5, 1, 2, 4];

/** Pause between one replay frame arriving and the next step, at 1x, ms. Simulator choice:
 * playback moves one logged command at a time, not by the log's clock: a session's commands
 * are seconds apart while a drag or a held key sends bursts milliseconds apart, so the log's
 * spacing would stall on thinking time and flash through the bursts; 600 ms leaves time to read
 * an event's label before the next step. */
export const BASE_STEP_MS = 600;

/** Half the width of the range input's thumb in Chromium and Firefox (16 px thumbs), px: the
 * ticks sit between these insets so a tick lines up with the thumb at its step. Source: the
 * default `::-webkit-slider-thumb` / `::-moz-range-thumb` size of both engines. */
export const THUMB_INSET_PX = 8;

/** How each kind of event is ticked: colour, shape (an SVG path in a 12 x 12 box) and name.
 * Colours: the Okabe-Ito colour-blind-safe palette (Okabe & Ito 2008, "Color Universal
 * Design"), vermillion kept for safety violations; each kind also has its own shape, so colour
 * is never the only cue (WCAG 2.2, 1.4.1). */
export const EVENT_STYLES = {
  image: { colour: '#0072b2', shape: 'square', path: 'M2 2H10V10H2Z', name: 'Image (shot or live fluoroscopy)' },
  puncture: { colour: '#e69f00', shape: 'triangle-down', path: 'M1 2H11L6 11Z', name: 'Skin puncture' },
  loss_of_resistance: { colour: '#009e73', shape: 'diamond', path: 'M6 0L12 6L6 12L0 6Z', name: 'Loss of resistance' },
  injection: { colour: '#56b4e9', shape: 'circle', path: 'M6 1A5 5 0 1 1 5.99 1Z', name: 'Injection' },
  bone_contact: { colour: '#cc79a7', shape: 'triangle-up', path: 'M6 1L11 10H1Z', name: 'Bone contact' },
  violation: { colour: '#d55e00', shape: 'cross', path: 'M1 3L3 1L6 4L9 1L11 3L8 6L11 9L9 11L6 8L3 11L1 9L4 6Z', name: 'Safety violation' },
  submit: { colour: '#6b6b6b', shape: 'bar', path: 'M4 0H8V12H4Z', name: 'Submit' },
};

/** The style of an event kind; an unknown kind (a newer server) gets a neutral bar. */
export function eventStyle(kind) {
  return EVENT_STYLES[kind] || { colour: '#6b6b6b', shape: 'bar', path: 'M5 0H7V12H5Z', name: String(kind) };
}

/** The pause after a frame arrives before the next step at `speed`, ms. */
export function stepInterval(speed) {
  const s = Number(speed);
  if (!Number.isFinite(s) || s <= 0) throw new RangeError(`speed must be positive: ${speed}`);
  return BASE_STEP_MS / s;
}

/** Where each event's tick goes: `fraction` of the bar (step / steps, 0 at step 0, 1 at the
 * last step) and `row`, 0 for the first event at its step and 1, 2, ... for the ones after it,
 * so ticks of one step stack instead of hiding each other. In the events' order. */
export function tickLayout(events, steps) {
  const n = Math.max(1, Number(steps) || 0);
  const rows = new Map();
  return events.map((e, index) => {
    const step = Math.min(Math.max(0, e.step), n);
    const row = rows.get(step) || 0;
    rows.set(step, row + 1);
    return { index, step, fraction: step / n, row, kind: e.kind, style: eventStyle(e.kind), event: e };
  });
}

/** The CSS `left` of a tick at `fraction`: inset by the thumb's half width at both ends. */
export function tickLeft(fraction) {
  return `calc(${THUMB_INSET_PX}px + ${fraction} * (100% - ${2 * THUMB_INSET_PX}px))`;
}

/** Session time as a person reads it: `83.4 s`, `2 min 05 s`. */
export function clock(tMs) {
  const s = Math.max(0, Number(tMs) || 0) / 1000;
  if (s < 60) return `${s.toFixed(1)} s`;
  const m = Math.floor(s / 60);
  return `${m} min ${String(Math.floor(s - 60 * m)).padStart(2, '0')} s`;
}

/** One event in words, for its button and its tick's tooltip. */
export function eventText(e) {
  return `Step ${e.step}, ${clock(e.t_ms)}: ${e.label}`;
}

/** The events logged at exactly `step`. */
export function eventsAt(events, step) {
  return events.filter((e) => e.step === step);
}

/** What the live region says at `step`: the position and the events of that step. */
export function announcement(events, step, steps) {
  const here = eventsAt(events, step).map((e) => e.label);
  const at = step === 0 ? `Start (step 0 of ${steps})` : `Step ${step} of ${steps}`;
  return here.length ? `${at}: ${here.join('; ')}.` : `${at}.`;
}

/** The step of the next (`dir` 1) or previous (`dir` -1) event strictly after/before `step`,
 * or null when there is none. */
export function neighbourEventStep(events, step, dir) {
  const steps = [...new Set(events.map((e) => e.step))].sort((a, b) => a - b);
  if (dir > 0) return steps.find((s) => s > step) ?? null;
  const before = steps.filter((s) => s < step);
  return before.length ? before[before.length - 1] : null;
}

/** A step clamped into 0..=steps (whole numbers). */
export function clampStep(step, steps) {
  const s = Math.round(Number(step) || 0);
  return Math.min(Math.max(0, s), Math.max(0, steps));
}

/**
 * Loads replay frames one at a time. `request(step)` asks for a step's frame: when none is in
 * flight it is fetched at once, else it replaces any waiting request (an older waiting step is
 * never fetched: scrubbing or fast playback cannot flood the server). A frame whose step is no
 * longer the newest asked for is dropped instead of shown. `fetchFrame(step)` resolves to what
 * `show(step, frame)` draws (`null` for "no image yet"); failures go to `fail(step, error)`.
 */
export class FrameLoader {
  constructor(fetchFrame, show, fail = () => {}) {
    this.fetchFrame = fetchFrame;
    this.show = show;
    this.fail = fail;
    /** The step being fetched, or null. */
    this.inFlight = null;
    /** The step waiting for the one in flight, or null. */
    this.waiting = null;
    /** The newest step asked for. */
    this.wanted = null;
    /** Steps fetched, in order (for tests and diagnostics). */
    this.fetched = [];
    this.idleWaiters = [];
  }

  /** Asks for the frame of `step`. */
  request(step) {
    this.wanted = step;
    if (this.inFlight !== null) {
      this.waiting = step === this.inFlight ? null : step;
      return;
    }
    this.start(step);
  }

  /** Whether nothing is in flight or waiting. */
  get idle() {
    return this.inFlight === null && this.waiting === null;
  }

  /** Resolves once nothing is in flight or waiting (the newest frame is shown or failed). */
  whenIdle() {
    if (this.idle) return Promise.resolve();
    return new Promise((resolve) => this.idleWaiters.push(resolve));
  }

  start(step) {
    this.inFlight = step;
    this.fetched.push(step);
    Promise.resolve()
      .then(() => this.fetchFrame(step))
      // A stale frame is dropped; `show` may be async (decoding), and idle waits for it.
      .then((frame) => (step === this.wanted ? this.show(step, frame) : undefined))
      .catch((error) => { if (step === this.wanted) this.fail(step, error); })
      .finally(() => {
        this.inFlight = null;
        const next = this.waiting;
        this.waiting = null;
        if (next !== null) {
          this.start(next);
        } else {
          const waiters = this.idleWaiters;
          this.idleWaiters = [];
          for (const w of waiters) w();
        }
      });
  }
}
