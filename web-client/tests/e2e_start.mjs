// Session start in headless Chromium, as a learner meets it when the server is busy: the learner
// opens a station and, until the session can start, reads why in the page (the anatomy's
// preparation stage and progress as the server reports them, or that every session slot is
// taken); then the live session opens by itself and the first shot shows an image.
//
// Usage: node tests/e2e_start.mjs <base-url> [out-dir]
// Prints one JSON object: `messages` (each distinct text the page showed while waiting, in
// order), `waited_ms` (station click to live session), `first_image_ms` (Shot click to the
// first drawn frame) and the first image's mean grey level.

import { STEP_TIMEOUT_MS, waitUntil, login, runReport, expectHttpError } from './harness.mjs';

const base = process.argv[2];
if (!base) {
  console.error('usage: node tests/e2e_start.mjs <base-url> [out-dir]');
  process.exit(2);
}
// The session request is answered 503 while the anatomy is prepared or every slot is taken.
expectHttpError(/^\/api\/attempts\/[^/]+\/session$/, 503);

runReport(async (page, report) => {
  await page.goto(base);
  await page.waitForSelector('#login-view:not([hidden])');
  await login(page, 'learner@demo.invalid');
  await page.waitForSelector('#learner-view:not([hidden])');
  const clicked = Date.now();
  await page.locator('#station-list button').first().click();
  report.steps.push('station opened');
  const messages = [];
  const deadline = Date.now() + 2 * STEP_TIMEOUT_MS;
  for (;;) {
    const [msg, live] = await page.evaluate(() => [
      document.getElementById('message').textContent,
      !document.getElementById('session-view').hidden && document.getElementById('conn').textContent === 'live',
    ]);
    if (msg && messages[messages.length - 1] !== msg) messages.push(msg);
    if (live) break;
    if (Date.now() > deadline) throw new Error(`no live session; the page said ${JSON.stringify(messages)}`);
    await new Promise((r) => setTimeout(r, 50));
  }
  report.messages = messages;
  report.waited_ms = Date.now() - clicked;
  report.steps.push('live');
  const shot = Date.now();
  await page.click('#shot');
  await waitUntil(page, () => window.__sim && window.__sim.stats.frames > 0
    && Number(document.getElementById('frame-count').textContent) === window.__sim.stats.frames);
  report.first_image_ms = Date.now() - shot;
  report.first_image_mean = await page.evaluate(() => {
    const c = document.getElementById('fluoro');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let sum = 0;
    for (let i = 0; i < d.length; i += 4) sum += d[i];
    return sum / (d.length / 4);
  });
  report.steps.push('first image');
});
