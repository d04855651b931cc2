// The debrief of one submitted attempt (`/debrief.html?attempt=<uuid>`), for its learner and
// for faculty and admins of its course: the technical result with each criterion explained,
// the reveal (the last image with the structures the needle passed through outlined) and the
// replay bar (play, pause, step, speed, event ticks). The logic that needs no DOM lives in
// replay-bar.js and debrief-model.js (unit tested under node).

import { api, setCsrf, ApiError } from './api.js';
import {
  SPEEDS, BASE_STEP_MS, EVENT_STYLES, eventStyle, stepInterval, tickLayout, tickLeft, eventText,
  announcement, clampStep, neighbourEventStep, FrameLoader,
} from './replay-bar.js';
import {
  showValue, toleranceWords, statusWords, outcomeWords, scoreWords, structureWords, failedSafety,
  revealDrawing,
} from './debrief-model.js';

const $ = (id) => document.getElementById(id);
const SVG = 'http://www.w3.org/2000/svg';

/** Retries while the anatomy is prepared (503), at most this many. Simulator choice: the
 * preparation of a phantom takes a minute or two; 40 retries at the server's advised delay
 * (a few seconds) outlast it without retrying forever. */
const MAX_PREPARING_RETRIES = 40;
/** Fallback delay between those retries when the server gives none, ms. Simulator choice: the
 * order of the server's own `retry_after_s` advice. */
const PREPARING_RETRY_MS = 3000;
/** Vertical spacing of ticks stacked at one step, px. Simulator choice: the 12 px tick plus a
 * 1 px gap. */
const TICK_ROW_PX = 13;

function el(tag, props = {}, ...children) {
  const e = document.createElement(tag);
  Object.assign(e, props);
  for (const c of children) if (c !== null && c !== undefined) e.append(c);
  return e;
}

/** A 12 x 12 SVG of an event kind's tick shape (decorative: the text beside it says it). */
function shapeIcon(kind) {
  const style = eventStyle(kind);
  const svg = document.createElementNS(SVG, 'svg');
  svg.setAttribute('viewBox', '0 0 12 12');
  svg.setAttribute('width', '12');
  svg.setAttribute('height', '12');
  svg.setAttribute('aria-hidden', 'true');
  svg.setAttribute('focusable', 'false');
  svg.classList.add('tick-shape', `tick-${style.shape}`);
  const path = document.createElementNS(SVG, 'path');
  path.setAttribute('d', style.path);
  path.setAttribute('fill', style.colour);
  svg.append(path);
  return svg;
}

function setState(state, text) {
  const main = $('main');
  main.dataset.state = state;
  main.setAttribute('aria-busy', state === 'loading' ? 'true' : 'false');
  if (text !== undefined) $('status').textContent = text;
}

function say(text) {
  $('message').textContent = text || '';
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** An API call that waits out the anatomy's preparation (503) with the server's advice. */
async function apiPatient(path) {
  for (let i = 0; ; i++) {
    try {
      return await api('GET', path);
    } catch (e) {
      if (!(e instanceof ApiError) || e.status !== 503 || i >= MAX_PREPARING_RETRIES) throw e;
      const s = Number(e.detail && e.detail.retry_after_s);
      const wait = Number.isFinite(s) && s > 0 ? s * 1000 : PREPARING_RETRY_MS;
      setState('loading', `The anatomy is being prepared; trying again in ${Math.round(wait / 1000)} s…`);
      await sleep(wait);
    }
  }
}

// ------------------------------------------------------------------------- frames

/** Frame requests in flight now and at most at once (the page never asks for two at a time). */
const frameStats = { inFlight: 0, maxInFlight: 0, requests: 0 };

/** The tail of the frame requests: the reveal's and the replay's frames queue behind each
 * other, so one frame is requested at a time on the whole page. */
let frameChain = Promise.resolve();

/** The replay frame after the first `step` commands: an ImageBitmap, or null before the first
 * image (204). Queued behind any other frame request of the page. */
function fetchFrame(attemptId, step) {
  const run = frameChain.then(() => fetchFrameNow(attemptId, step));
  frameChain = run.catch(() => {});
  return run;
}

async function fetchFrameNow(attemptId, step) {
  frameStats.inFlight += 1;
  frameStats.requests += 1;
  frameStats.maxInFlight = Math.max(frameStats.maxInFlight, frameStats.inFlight);
  try {
    for (let i = 0; ; i++) {
      const r = await fetch(`/api/attempts/${attemptId}/replay/frame?step=${step}`, { credentials: 'same-origin' });
      if (r.status === 204) return null;
      if (r.status === 503 && i < MAX_PREPARING_RETRIES) {
        await sleep(PREPARING_RETRY_MS);
        continue;
      }
      if (!r.ok) throw new Error(`the frame at step ${step} could not be loaded (HTTP ${r.status})`);
      return await createImageBitmap(await r.blob());
    }
  } finally {
    frameStats.inFlight -= 1;
  }
}

/** Draws `bitmap` on `canvas` at its own size (black with nothing). */
function drawFrame(canvas, bitmap) {
  const ctx = canvas.getContext('2d');
  if (bitmap) {
    if (canvas.width !== bitmap.width) canvas.width = bitmap.width;
    if (canvas.height !== bitmap.height) canvas.height = bitmap.height;
    ctx.drawImage(bitmap, 0, 0);
  } else {
    ctx.fillStyle = '#000';
    ctx.fillRect(0, 0, canvas.width, canvas.height);
  }
}

// ------------------------------------------------------------------------- summary and criteria

function renderSummary(detail, debrief, me) {
  const a = detail.attempt;
  document.title = `Debrief: ${a.station_id} — pain-sim`;
  $('title').textContent = `Debrief: ${a.station_id}`;
  $('station').textContent = a.station_id;
  $('learner').textContent = a.learner_id === me.user.id ? `${a.learner_name} (you)` : `${a.learner_name} (${a.learner_email})`;
  $('mode').textContent = a.mode === 'assessment' ? 'Assessment' : 'Practice';
  $('attempt-state').textContent = {
    submitted: 'Submitted, awaiting faculty review', returned: 'Returned by faculty', approved: 'Approved by faculty',
  }[a.state] || a.state;
  const outcome = $('outcome');
  outcome.textContent = `${outcomeWords(debrief.outcome)} (a technical statement, not a certification)`;
  outcome.dataset.outcome = debrief.outcome || 'none';
  $('score').textContent = `${scoreWords(debrief.score)} (pass threshold ${scoreWords(debrief.pass_threshold)}; every safety criterion must also be met)`;
  $('notice').textContent = debrief.notice;
  const failed = failedSafety(debrief.criteria);
  $('safety-failed').hidden = failed.length === 0;
  $('safety-failed').textContent = failed.length
    ? `Safety criterion not met: ${failed.map((c) => c.description).join(' ')} A failed safety criterion alone makes the outcome not met, whatever the score.`
    : '';
  if (detail.reviews && detail.reviews.length) {
    const r = detail.reviews[detail.reviews.length - 1];
    $('reviews').hidden = false;
    $('reviews').textContent = `Faculty review: ${r.decision === 'approved' ? 'approved' : 'returned'} by ${r.reviewer_name}${r.comment ? `: “${r.comment}”` : '.'}`;
  }
  $('summary').hidden = false;
}

function renderCriteria(criteria) {
  const rows = criteria.map((c) => {
    const name = el('th', { scope: 'row' }, el('span', { textContent: c.description }));
    if (c.critical) name.append(' ', el('span', { className: 'badge safety-badge', textContent: 'Safety' }));
    name.append(el('span', { className: 'criterion-id muted', textContent: c.id }));
    const status = el('td', { className: `status status-${c.status}` });
    status.append(statusWords(c.status));
    if (c.critical && c.status === 'not_met') status.append(el('strong', { className: 'safety-fail-text', textContent: ' — safety criterion failed' }));
    const tr = el('tr', {},
      name,
      el('td', { className: 'value', textContent: showValue(c.value, c.unit) }),
      el('td', { textContent: toleranceWords(c.tolerance, c.unit) }),
      status,
      el('td', { textContent: c.explanation }));
    tr.dataset.criterion = c.id;
    tr.dataset.status = c.status;
    if (c.critical) tr.classList.add('critical');
    if (c.critical && c.status === 'not_met') tr.classList.add('safety-fail');
    return tr;
  });
  $('criteria').tBodies[0].replaceChildren(...rows);
  $('criteria-section').hidden = false;
}

// ------------------------------------------------------------------------- reveal

async function renderReveal(attemptId) {
  $('reveal-section').hidden = false;
  $('reveal-status').textContent = 'Loading the reveal…';
  let reveal;
  try {
    reveal = await apiPatient(`/api/attempts/${attemptId}/reveal`);
  } catch (e) {
    $('reveal-status').textContent = e instanceof ApiError && e.status === 404
      ? 'No reveal: the session had no needle or no fluoroscopy image.'
      : `The reveal could not be loaded: ${e.message}`;
    return;
  }
  const canvas = $('reveal-canvas');
  const bitmap = await fetchFrame(attemptId, reveal.step);
  canvas.width = reveal.width;
  canvas.height = reveal.height;
  const ctx = canvas.getContext('2d');
  ctx.fillStyle = '#000';
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  if (bitmap) ctx.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
  const drawing = revealDrawing(reveal, canvas.width);
  for (const layer of drawing.layers) {
    ctx.fillStyle = layer.colour;
    for (const r of layer.rects) ctx.fillRect(r.x, r.y, r.w, r.h);
  }
  const names = reveal.touched.map(structureWords);
  canvas.setAttribute('aria-label', names.length
    ? `The last fluoroscopy image of the session, with the outlines of the structures the needle passed through: ${names.join(', ')}.`
    : 'The last fluoroscopy image of the session; the needle passed through no outlined structure.');
  $('reveal-legend').replaceChildren(...reveal.touched.map((s) => {
    const colour = drawing.colours.get(s);
    const outlined = !drawing.unoutlined.includes(s);
    const swatch = el('span', { className: 'swatch' });
    swatch.setAttribute('aria-hidden', 'true');
    swatch.style.background = outlined ? colour : 'transparent';
    const li = el('li', {}, swatch, el('span', { textContent: structureWords(s) }));
    if (!outlined) li.append(el('span', { className: 'muted', textContent: ' (not outlined: an envelope such as the skin)' }));
    li.dataset.structure = s;
    if (outlined) li.dataset.colour = colour;
    return li;
  }));
  if (!reveal.touched.length) $('reveal-legend').replaceChildren(el('li', { textContent: 'None.' }));
  $('reveal-status').textContent = bitmap ? '' : 'The session had no image at its end.';
  $('reveal-body').hidden = false;
  canvas.dataset.drawn = 'true';
}

// ------------------------------------------------------------------------- replay bar

/** The replay bar of `attemptId` over `steps` logged commands and their `events`. */
function setUpReplay(attemptId, steps, events) {
  const range = $('replay-step');
  const canvas = $('replay-canvas');
  let step = 0;
  let playing = false;
  let playGeneration = 0;
  let timer = null;

  const loader = new FrameLoader(
    (k) => fetchFrame(attemptId, k),
    (k, bitmap) => {
      drawFrame(canvas, bitmap);
      canvas.dataset.step = String(k);
      canvas.dataset.frame = bitmap ? 'image' : 'none';
      canvas.dataset.frames = String(Number(canvas.dataset.frames || 0) + 1);
      $('replay-empty').hidden = !!bitmap;
      canvas.setAttribute('aria-label', bitmap
        ? `Replay frame: the image on screen after step ${k} of ${steps}.`
        : `Replay frame: no image yet at step ${k} of ${steps}.`);
    },
    (k, e) => say(`Replay: ${e.message}`),
  );
  window.__debrief = { loader, frameStats };

  const speedSelect = $('replay-speed');
  speedSelect.replaceChildren(...SPEEDS.map((s) => el('option', { value: String(s), textContent: `${s}×`, selected: s === 1 })));
  const pace = () => `Play shows one logged command at a time and waits ${(stepInterval(Number(speedSelect.value)) / 1000).toFixed(2)} s after each frame arrives (${BASE_STEP_MS / 1000} s at 1×).`;
  $('replay-pace').textContent = pace();
  speedSelect.addEventListener('change', () => { $('replay-pace').textContent = pace(); });

  range.max = String(steps);
  const layout = tickLayout(events, steps);
  $('replay-ticks').replaceChildren(...layout.map((t) => {
    const tick = el('span', { className: `tick tick-kind-${t.kind}`, title: eventText(t.event) });
    tick.style.left = tickLeft(t.fraction);
    tick.style.top = `${t.row * TICK_ROW_PX}px`;
    tick.dataset.step = String(t.step);
    tick.dataset.kind = t.kind;
    tick.append(shapeIcon(t.kind));
    tick.addEventListener('click', () => { pause(); go(t.step, true); });
    return tick;
  }));
  const rows = Math.max(1, ...layout.map((t) => t.row + 1));
  $('replay-ticks').style.height = `${rows * TICK_ROW_PX}px`;

  // The key lists the kinds present, in the order of EVENT_STYLES (unknown kinds last).
  const rank = (k) => { const i = Object.keys(EVENT_STYLES).indexOf(k); return i < 0 ? 1e9 : i; };
  const kinds = [...new Set(events.map((e) => e.kind))].sort((a, b) => rank(a) - rank(b));
  $('tick-key').replaceChildren(...kinds.map((k) => el('li', {}, shapeIcon(k), ` ${eventStyle(k).name}`)));

  const buttons = events.map((e) => {
    const b = el('button', { type: 'button', className: 'event-button' }, shapeIcon(e.kind), ` ${eventText(e)}`);
    b.dataset.step = String(e.step);
    b.dataset.kind = e.kind;
    if (e.kind === 'violation') b.classList.add('violation');
    b.addEventListener('click', () => { pause(); go(e.step, true); });
    return b;
  });
  $('event-list').replaceChildren(...buttons.map((b) => el('li', {}, b)));

  function go(k, announce) {
    step = clampStep(k, steps);
    range.value = String(step);
    const words = announcement(events, step, steps);
    range.setAttribute('aria-valuetext', words);
    $('replay-position').textContent = step === 0 ? `Start, step 0 of ${steps}` : `Step ${step} of ${steps}`;
    for (const b of buttons) {
      if (Number(b.dataset.step) === step) b.setAttribute('aria-current', 'step');
      else b.removeAttribute('aria-current');
    }
    if (announce) $('replay-live').textContent = words;
    loader.request(step);
    $('replay-loading').hidden = false;
    loader.whenIdle().then(() => { if (loader.idle) $('replay-loading').hidden = true; });
  }

  function setPlaying(on, words) {
    playing = on;
    $('replay-play').setAttribute('aria-pressed', on ? 'true' : 'false');
    $('replay-section').dataset.playing = on ? 'true' : 'false';
    $('replay-state').textContent = on ? `Playing at ${speedSelect.value}×` : 'Paused';
    if (words) $('replay-live').textContent = words;
  }

  function pause() {
    if (!playing) return;
    playGeneration += 1;
    clearTimeout(timer);
    setPlaying(false, `Paused. ${announcement(events, step, steps)}`);
  }

  /** Waits for the current frame, then the speed's interval, then moves one step on. */
  function scheduleNext() {
    const generation = playGeneration;
    loader.whenIdle().then(() => {
      if (!playing || generation !== playGeneration) return;
      timer = setTimeout(() => {
        if (!playing || generation !== playGeneration) return;
        if (step >= steps) {
          playGeneration += 1;
          setPlaying(false, `End of the replay. ${announcement(events, step, steps)}`);
          return;
        }
        go(step + 1, false);
        scheduleNext();
      }, stepInterval(Number(speedSelect.value)));
    });
  }

  $('replay-play').addEventListener('click', () => {
    if (playing) return;
    if (step >= steps) go(0, false);
    playGeneration += 1;
    setPlaying(true, `Playing at ${speedSelect.value}×.`);
    scheduleNext();
  });
  $('replay-pause').addEventListener('click', pause);
  $('replay-back').addEventListener('click', () => { pause(); go(step - 1, true); });
  $('replay-forward').addEventListener('click', () => { pause(); go(step + 1, true); });
  range.addEventListener('input', () => { pause(); go(Number(range.value), true); });
  for (const [id, dir] of [['replay-prev-event', -1], ['replay-next-event', 1]]) {
    $(id).addEventListener('click', () => {
      pause();
      const k = neighbourEventStep(events, step, dir);
      if (k === null) $('replay-live').textContent = dir > 0 ? 'No later event.' : 'No earlier event.';
      else go(k, true);
    });
  }
  speedSelect.addEventListener('change', () => {
    if (playing) $('replay-state').textContent = `Playing at ${speedSelect.value}×`;
  });

  $('replay-section').hidden = false;
  // Open on the first image (before it the replay has nothing to show), else at the start.
  const firstImage = events.find((e) => e.kind === 'image');
  go(firstImage ? firstImage.step : 0, false);
}

// ------------------------------------------------------------------------- page

async function main() {
  const attemptId = new URLSearchParams(location.search).get('attempt') || '';
  if (!/^[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}$/i.test(attemptId)) {
    setState('error', '');
    say('No attempt given: open this page from "My attempts" or the faculty review (debrief.html?attempt=<id>).');
    return;
  }
  let me;
  try {
    me = await api('GET', '/api/auth/me');
  } catch (e) {
    if (e instanceof ApiError && e.status === 401) {
      setState('login', '');
      $('login-link').hidden = false;
      return;
    }
    throw e;
  }
  setCsrf(me.csrf_token);
  $('who').textContent = `Signed in as ${me.user.display_name} (${me.user.role})`;
  let detail;
  try {
    detail = await api('GET', `/api/attempts/${attemptId}`);
  } catch (e) {
    setState('error', '');
    say(e instanceof ApiError && e.status === 404 ? 'No such attempt, or it is not one you may see.' : `The attempt could not be loaded: ${e.message}`);
    return;
  }
  if (detail.attempt.state === 'in_progress') {
    setState('not-submitted', 'This attempt is not submitted yet: its debrief opens once it is submitted.');
    $('title').textContent = `Debrief: ${detail.attempt.station_id}`;
    return;
  }
  let debrief;
  try {
    debrief = await apiPatient(`/api/attempts/${attemptId}/debrief`);
  } catch (e) {
    if (e instanceof ApiError && e.status === 409) {
      setState('not-submitted', 'This attempt is not submitted yet: its debrief opens once it is submitted.');
    } else if (e instanceof ApiError && e.status === 404) {
      setState('error', '');
      say('This attempt has no recorded simulation session, so there is nothing to debrief.');
    } else {
      setState('error', '');
      say(`The debrief could not be loaded: ${e.message}`);
    }
    return;
  }
  renderSummary(detail, debrief, me);
  renderCriteria(debrief.criteria);
  setUpReplay(attemptId, debrief.steps, debrief.events);
  setState('ready', `Debrief of ${debrief.criteria.length} criteria and ${debrief.events.length} events.`);
  await renderReveal(attemptId);
  $('main').dataset.reveal = 'done';
}

main().catch((e) => {
  setState('error', '');
  say(`Something went wrong: ${e.message}`);
});
