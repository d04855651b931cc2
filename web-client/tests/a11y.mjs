// Accessibility of every screen: axe-core (web-client/node_modules, injected into the page
// through the DevTools protocol, so the server's Content-Security-Policy is not loosened) with
// the WCAG 2.0 and 2.1 A and AA rules, on each screen a learner, a faculty member and an admin
// reach: login, stations, fluoroscopy session, ultrasound session, result, debrief, review
// queue, review, cohort dashboard, LTI admin. Driven by server/tests/e2e_a11y.rs; prints one JSON
// line with the violations per screen (the Rust test wants none).
//
//   node tests/a11y.mjs BASE_URL SCREENSHOT_DIR
//
// Each screen is also photographed, at 1440 x 900 CSS pixels rendered at half scale (720 x 450
// PNGs), into SCREENSHOT_DIR: `PAINSIM_E2E_SCREENSHOTS=docs cargo test -p server --test tests
// -- e2e_a11y` regenerates docs/screens/, which the README shows.

import { mkdirSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';

import { axeViolations, login, runReport, waitUntil, expectHttpError, WCAG_21_AA } from './harness.mjs';

const base = process.argv[2];
const shots = process.argv[3];
/** The rule sets: WCAG 2.1 level A and AA, with 2.0's. */
const TAGS = WCAG_21_AA;

// The debrief and review replay the session on the server, which answers 503 while the
// anatomy is prepared (the pages retry); and 409 before a submit is by design.
expectHttpError(/^\/api\/attempts\/[^/]+\/(debrief|reveal|replay)/, 503);

async function audit(page, screen, report) {
  const violations = await axeViolations(page, TAGS);
  report.screens.push({ screen, violations });
  if (shots) {
    const file = `${screen.replace(/[^a-z0-9]+/gi, '-').toLowerCase()}.png`;
    writeFileSync(join(shots, file), await halfScalePng(page));
  }
}

/** The page as a PNG at half its CSS size (small enough to commit), scaled by the browser. */
async function halfScalePng(page) {
  const full = (await page.screenshot()).toString('base64');
  const half = await page.evaluate(async (b64) => {
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const bitmap = await createImageBitmap(new Blob([bytes], { type: 'image/png' }));
    const canvas = new OffscreenCanvas(Math.round(bitmap.width / 2), Math.round(bitmap.height / 2));
    const ctx = canvas.getContext('2d');
    ctx.imageSmoothingQuality = 'high';
    ctx.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
    const blob = await canvas.convertToBlob({ type: 'image/png' });
    const out = new Uint8Array(await blob.arrayBuffer());
    let text = '';
    for (let i = 0; i < out.length; i += 0x8000) text += String.fromCharCode(...out.subarray(i, i + 0x8000));
    return btoa(text);
  }, full);
  return Buffer.from(half, 'base64');
}

async function logOut(page) {
  await page.click('#logout');
  await page.waitForSelector('#login-view:not([hidden])');
}

await runReport(async (page, report) => {
  report.screens = [];
  if (shots) mkdirSync(shots, { recursive: true });
  // A 1440 x 900 screen (the reference size of the layout), photographed at half scale.
  await page.setViewportSize({ width: 1440, height: 900 });
  report.axe_tags = TAGS;

  await page.goto(base);
  await page.waitForSelector('#login-view:not([hidden])');
  await audit(page, 'login', report);

  await login(page, 'learner@demo.invalid');
  await page.waitForSelector('#learner-view:not([hidden])');
  await audit(page, 'stations', report);

  await page.locator('#station-list button').first().click();
  await page.waitForSelector('#session-view:not([hidden])');
  await waitUntil(page, () => document.getElementById('conn').textContent === 'live');
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  await page.keyboard.press('x');
  await waitUntil(page, () => document.getElementById('fluoro-wait').hidden);
  await page.keyboard.press('s');
  await waitUntil(page, () => document.querySelectorAll('#stored-images li').length === 1);
  await page.click('#stored-images li:first-child button');
  await audit(page, 'fluoroscopy session', report);
  // The key map dialog, open.
  await page.keyboard.press('?');
  await page.waitForSelector('dialog[open]');
  await audit(page, 'key map dialog', report);
  await page.keyboard.press('Escape');

  // The ultrasound panel of the same station: a probe in hand and a B-mode image.
  await page.selectOption('#us-probe', 'linear-probe');
  await waitUntil(page, () => window.__sim.us && window.__sim.us.outcome && window.__sim.us.outcome.probe === 'linear');
  // The full B-mode frame of the linear probe (a draft with its "Preview" badge comes first).
  await waitUntil(page, () => {
    const d = window.__sim.us.drawn.ultrasound;
    const seq = window.__sim.live.seq;
    // A state query (sent after some commands) changes no view.
    const want = seq === window.__sim.us.lastQuerySeq ? seq - 1 : seq;
    return window.__sim.live.pending.size === 0 && !!d && d.inputSeq >= want && !d.draft;
  });
  await page.locator('#bmode').scrollIntoViewIfNeeded();
  await audit(page, 'ultrasound session', report);

  report.attempt = await page.evaluate(() => window.__sim.session.attempt_id);
  await page.click('#submit');
  await page.waitForSelector('#result:not([hidden])');
  await audit(page, 'result', report);

  await page.goto(`${base.replace(/\/$/, '')}/debrief.html?attempt=${encodeURIComponent(report.attempt)}`);
  await waitUntil(page, () => {
    const m = document.getElementById('main');
    return m && m.dataset.state === 'ready' && m.dataset.reveal === 'done';
  }, null, { timeout: 120_000 });
  await audit(page, 'debrief', report);

  await page.goto(base);
  await page.waitForSelector('#learner-view:not([hidden])');
  await logOut(page);
  await login(page, 'faculty@demo.invalid');
  await page.waitForSelector('#faculty-view:not([hidden])');
  await waitUntil(page, () => document.querySelectorAll('#queue tbody tr').length > 0);
  await audit(page, 'review queue', report);
  await page.locator('#queue tbody button').first().click();
  await page.waitForSelector('#review:not([hidden])');
  await audit(page, 'review', report);

  const cohort = await page.getAttribute('#cohort-links a', 'href');
  await page.goto(new URL(cohort, base).href);
  await waitUntil(page, () => {
    const view = document.getElementById('cohort-view');
    const status = document.getElementById('status');
    return view && !view.hidden && status && status.textContent.startsWith('Showing');
  }, null, { timeout: 120_000 });
  await audit(page, 'cohort dashboard', report);

  await page.goto(base);
  await page.waitForSelector('#faculty-view:not([hidden])');
  await logOut(page);
  await login(page, 'admin@demo.invalid');
  await waitUntil(page, () => document.getElementById('login-view').hidden);
  await page.goto(`${base.replace(/\/$/, '')}/lti-admin.html`);
  await page.waitForSelector('#platforms');
  await audit(page, 'LTI admin', report);
});
