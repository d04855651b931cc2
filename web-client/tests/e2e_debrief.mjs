// The debrief page (debrief.html) in headless Chromium, against a server holding one submitted
// attempt of the demo learner (a scripted session with shots, two punctures, a bone contact,
// injections and a submit: server/tests/e2e_debrief.rs) and one attempt still in progress.
// The learner opens the debrief: the criteria table, the reveal (outline pixels of each
// touched structure's colour on the canvas, the legend in the order the needle entered them),
// the replay bar (one tick per event, the event list, stepping changes the frame and announces
// the event, play advances the step); axe-core's WCAG 2 A/AA rules pass in light and dark;
// the in-progress attempt says it is not submitted yet; faculty see the same page.
//
// A second submitted attempt (E2E_REVEAL_ATTEMPT) punctured the dural sac: its reveal outlines
// the sac, and its failed safety criterion is prominent.
//
// Usage: E2E_ATTEMPT=<submitted attempt> E2E_REVEAL_ATTEMPT=<submitted attempt through the sac>
//        E2E_OPEN_ATTEMPT=<attempt in progress> node tests/e2e_debrief.mjs <base-url> [out-dir]
// Prints one JSON object on stdout (the figures the Rust test asserts on) and exits 0 when every
// step passed, 1 with {"ok": false, "error": ...} otherwise. Page captures go to out-dir.

import { mkdirSync } from 'node:fs';
import { join } from 'node:path';
import { axeViolations, login, runReport, waitUntil } from './harness.mjs';

const base = process.argv[2];
const outDir = process.argv[3] || null;
const attempt = process.env.E2E_ATTEMPT;
const openAttempt = process.env.E2E_OPEN_ATTEMPT;
const revealAttempt = process.env.E2E_REVEAL_ATTEMPT;
if (!base || !attempt || !openAttempt || !revealAttempt) {
  console.error('usage: E2E_ATTEMPT=<id> E2E_REVEAL_ATTEMPT=<id> E2E_OPEN_ATTEMPT=<id> node tests/e2e_debrief.mjs <base-url> [out-dir]');
  process.exit(2);
}
/** Playback at 4x must advance at least this many steps before the script pauses it.
 * Test choice: 3 steps show that playback carries on by itself past a single step. */
const PLAY_MIN_STEPS = 3;

async function capture(page, name) {
  if (!outDir) return;
  mkdirSync(outDir, { recursive: true });
  await page.screenshot({ path: join(outDir, `${name}.png`), fullPage: true });
}

async function logInAs(page, email) {
  await page.context().clearCookies();
  await page.goto(base);
  await page.waitForSelector('#login-view:not([hidden])');
  await login(page, email);
  await waitUntil(page, () => !document.getElementById('login-view') || document.getElementById('login-view').hidden);
}

/** Opens the debrief of `id` and waits until it has settled (ready with the reveal drawn, or a
 * final message). */
async function openDebrief(page, id) {
  await page.goto(`${base}debrief.html?attempt=${id}`);
  await waitUntil(page, () => {
    const m = document.getElementById('main');
    return m && (m.dataset.state === 'ready' ? m.dataset.reveal === 'done' : m.dataset.state !== 'loading');
  });
  return page.evaluate(() => ({
    state: document.getElementById('main').dataset.state,
    status: document.getElementById('status').textContent,
    message: document.getElementById('message').textContent,
  }));
}

/** The page's visible content, for the report and the comparison between accounts. */
function pageContent() {
  const text = (id) => document.getElementById(id).textContent.trim();
  const rows = [...document.querySelectorAll('#criteria tbody tr')].map((tr) => ({
    id: tr.dataset.criterion,
    status: tr.dataset.status,
    critical: tr.classList.contains('critical'),
    cells: [...tr.cells].map((c) => c.textContent.trim()),
  }));
  const legend = [...document.querySelectorAll('#reveal-legend li')].map((li) => ({
    structure: li.dataset.structure, colour: li.dataset.colour || null, text: li.textContent.trim(),
  }));
  const ticks = [...document.querySelectorAll('#replay-ticks .tick')].map((t) => ({
    step: Number(t.dataset.step), kind: t.dataset.kind, title: t.title, left: t.getBoundingClientRect().left,
  }));
  const events = [...document.querySelectorAll('#event-list button')].map((b) => ({
    step: Number(b.dataset.step), kind: b.dataset.kind, text: b.textContent.trim(),
  }));
  return {
    title: text('title'),
    station: text('station'),
    outcome: text('outcome'),
    score: text('score'),
    notice: text('notice'),
    header_rows: [...document.querySelectorAll('#criteria thead th')].map((th) => th.textContent.trim()),
    rows,
    legend,
    reveal_label: document.getElementById('reveal-canvas').getAttribute('aria-label'),
    ticks,
    events,
    range_max: Number(document.getElementById('replay-step').max),
  };
}

/** Pixels of the reveal canvas that have exactly each legend colour. */
function revealPixels() {
  const c = document.getElementById('reveal-canvas');
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  const want = new Map();
  for (const li of document.querySelectorAll('#reveal-legend li[data-colour]')) {
    const n = parseInt(li.dataset.colour.slice(1), 16);
    want.set(n, li.dataset.structure);
  }
  const counts = Object.fromEntries([...want.values()].map((s) => [s, 0]));
  let grey = 0;
  for (let i = 0; i < d.length; i += 4) {
    const s = want.get((d[i] << 16) | (d[i + 1] << 8) | d[i + 2]);
    if (s) counts[s] += 1;
    else if (Math.abs(d[i] - d[i + 1]) <= 2 && Math.abs(d[i + 1] - d[i + 2]) <= 2) grey += 1;
  }
  return { width: c.width, height: c.height, counts, grey };
}

/** The replay canvas: its shown step and a 64 x 64 block-mean thumbnail of its grey levels. */
function replayFrame() {
  const c = document.getElementById('replay-canvas');
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  const thumb = new Array(64 * 64).fill(0);
  const n = c.width * c.height;
  for (let i = 0; i < n; i++) {
    const x = ((i % c.width) * 64 / c.width) | 0, y = (Math.floor(i / c.width) * 64 / c.height) | 0;
    thumb[y * 64 + x] += d[4 * i] * 64 * 64 / n;
  }
  return { step: Number(c.dataset.step), frame: c.dataset.frame, thumb, label: c.getAttribute('aria-label') };
}

/** Waits until the replay shows `step` and no frame is loading. */
async function frameAt(page, step) {
  await waitUntil(page, (k) => Number(document.getElementById('replay-canvas').dataset.step) === k
    && window.__debrief.loader.idle, step);
  return page.evaluate(replayFrame);
}

function meanAbsDiff(a, b) {
  let s = 0;
  for (let i = 0; i < a.thumb.length; i++) s += Math.abs(a.thumb[i] - b.thumb[i]);
  return s / a.thumb.length;
}

/** Controls without a name, images without a label, focus ring of a tabbed-to button. */
async function accessibility(page) {
  return page.evaluate(() => {
    const named = (e) => (e.getAttribute('aria-label') || e.textContent.trim() || (e.labels && e.labels.length && e.labels[0].textContent.trim()));
    return {
      unlabeled_buttons: [...document.querySelectorAll('button')].filter((b) => !named(b)).length,
      unlabeled_inputs: [...document.querySelectorAll('input, select')].filter((i) => !named(i)).length,
      unlabeled_images: [...document.querySelectorAll('[role="img"], img')].filter((i) => !i.getAttribute('aria-label') && !i.getAttribute('alt')).length,
      live_regions: document.querySelectorAll('[aria-live]').length,
    };
  });
}

/** axe-core's WCAG 2.0 A and AA rules on the page as it is now. */
const axe = (page) => axeViolations(page, ['wcag2a', 'wcag2aa']);

await runReport(async (page, report) => {
  // The learner's own submitted attempt.
  await logInAs(page, 'learner@demo.invalid');
  report.learner_open = await openDebrief(page, attempt);
  if (report.learner_open.state !== 'ready') throw new Error(`debrief not ready: ${JSON.stringify(report.learner_open)}`);
  report.learner = await page.evaluate(pageContent);
  report.steps.push('debrief');

  report.reveal = await page.evaluate(revealPixels);
  report.steps.push('reveal');
  await capture(page, 'debrief-learner');

  // Stepping: jump to the last image event by its button, one step back, then forward onto
  // it: the frame changes (a new shot of the needle moved since the one before) and the live
  // region announces the event.
  const images = report.learner.events.filter((e) => e.kind === 'image');
  const target = images[images.length - 1];
  const initial = await page.evaluate(() => Number(document.getElementById('replay-step').value));
  await page.locator('#event-list button').nth(report.learner.events.indexOf(target)).click();
  await frameAt(page, target.step);
  await page.click('#replay-back');
  const before = await frameAt(page, target.step - 1);
  const liveBack = await page.evaluate(() => document.getElementById('replay-live').textContent);
  await page.click('#replay-forward');
  const after = await frameAt(page, target.step);
  const liveForward = await page.evaluate(() => document.getElementById('replay-live').textContent);
  report.stepping = {
    initial_step: initial, target_step: target.step, target_label: target.text,
    before_step: before.step, after_step: after.step, after_frame: after.frame,
    mean_diff: meanAbsDiff(before, after), live_back: liveBack, live_forward: liveForward,
    frame_label: after.label,
    current_event: await page.evaluate(() => [...document.querySelectorAll('#event-list button[aria-current="step"]')].map((b) => b.textContent.trim())),
  };
  report.steps.push('stepped');

  // Keyboard: the range input takes the arrow keys (one step) with a visible focus ring.
  await page.focus('#replay-step');
  await page.keyboard.press('ArrowRight');
  const keyed = await frameAt(page, target.step + 1);
  report.keyboard = {
    step: keyed.step,
    focus_outline: await page.evaluate(() => {
      const s = getComputedStyle(document.activeElement);
      return { style: s.outlineStyle, width: s.outlineWidth };
    }),
  };

  // "Previous event" goes back to the event just left.
  await page.click('#replay-prev-event');
  report.keyboard.prev_event_step = (await frameAt(page, target.step)).step;

  // Play at 4x from the start: the step advances by itself; pause stops it.
  await page.selectOption('#replay-speed', '4');
  await page.locator('#event-list button').first().click();
  const start = (await frameAt(page, report.learner.events[0].step)).step;
  await page.click('#replay-play');
  const playingState = await page.evaluate(() => ({
    pressed: document.getElementById('replay-play').getAttribute('aria-pressed'),
    state: document.getElementById('replay-state').textContent,
  }));
  await waitUntil(page, (k) => Number(document.getElementById('replay-step').value) >= k, start + PLAY_MIN_STEPS);
  await page.click('#replay-pause');
  const paused = await page.evaluate(() => Number(document.getElementById('replay-step').value));
  await page.waitForTimeout(1500);
  report.play = {
    start, playing: playingState, paused_at: paused,
    after_pause: await page.evaluate(() => Number(document.getElementById('replay-step').value)),
    state_after: await page.evaluate(() => document.getElementById('replay-state').textContent),
    live_after: await page.evaluate(() => document.getElementById('replay-live').textContent),
    frame_stats: await page.evaluate(() => ({ ...window.__debrief.frameStats, fetched: window.__debrief.loader.fetched.length })),
  };
  report.steps.push('played');

  report.accessible = await accessibility(page);
  report.axe_light = await axe(page);
  await page.emulateMedia({ colorScheme: 'dark' });
  report.theme = { dark_bg: await page.evaluate(() => getComputedStyle(document.body).backgroundColor) };
  report.axe_dark = await axe(page);
  await capture(page, 'debrief-dark');
  await page.emulateMedia({ colorScheme: 'light' });
  report.theme.light_bg = await page.evaluate(() => getComputedStyle(document.body).backgroundColor);
  report.steps.push('accessible');

  // The attempt through the dural sac: outlines drawn, the failed safety criterion prominent.
  report.sac_open = await openDebrief(page, revealAttempt);
  report.sac = await page.evaluate(pageContent);
  report.sac_reveal = await page.evaluate(revealPixels);
  report.sac_safety = await page.evaluate(() => ({
    banner_shown: !document.getElementById('safety-failed').hidden,
    banner: document.getElementById('safety-failed').textContent,
    failed_rows: [...document.querySelectorAll('#criteria tr.safety-fail')].map((tr) => tr.textContent),
  }));
  report.axe_sac = await axe(page);
  await capture(page, 'debrief-sac');
  report.steps.push('sac');

  // An attempt still in progress: a clear message, no table.
  report.in_progress = await openDebrief(page, openAttempt);
  report.in_progress.rows = await page.evaluate(() => document.querySelectorAll('#criteria tbody tr').length);
  report.in_progress.summary_hidden = await page.evaluate(() => document.getElementById('summary').hidden);
  report.steps.push('in progress');

  // Faculty of the course: the same page for the same attempt.
  await logInAs(page, 'faculty@demo.invalid');
  report.faculty_open = await openDebrief(page, attempt);
  report.faculty = await page.evaluate(pageContent);
  report.faculty_reveal = await page.evaluate(revealPixels);
  await capture(page, 'debrief-faculty');
  await openDebrief(page, revealAttempt);
  report.faculty_sac_reveal = await page.evaluate(revealPixels);
  report.steps.push('faculty');

  // Logged out: a link to log in.
  await page.context().clearCookies();
  report.logged_out = await openDebrief(page, attempt);
  report.logged_out.link_shown = await page.evaluate(() => !document.getElementById('login-link').hidden);
  report.steps.push('logged out');
});
