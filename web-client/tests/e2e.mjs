// End-to-end run of the web client in headless Chromium (Debian's /usr/bin/chromium, driven by
// playwright-core): a learner logs in, opens a fluoroscopy station, takes a shot, rotates the
// C-arm, takes a shot, drags the skin marker on that image, punctures there in AP and advances
// the needle back in the rotated view, takes a shot, injects contrast under live
// fluoroscopy with the press-and-hold plunger and submits; then faculty
// log in, set up an authenticator (the code is computed here, as an authenticator app would),
// open the replay and approve.
//
// Usage: E2E_MARKER='{"orbitalDeg":30,"pixel":[x,y]}' node tests/e2e.mjs <base-url> [out-dir]
// Prints one JSON object on stdout (the figures the Rust test asserts on) and exits 0 when every
// step passed, 1 with {"ok": false, "error": ...} otherwise. Canvas captures go to out-dir.

import { createHmac } from 'node:crypto';
import { writeFileSync, mkdirSync } from 'node:fs';
import { join } from 'node:path';
import { STEP_TIMEOUT_MS, waitUntil, login, openFirstStation, runReport } from './harness.mjs';

const base = process.argv[2];
const outDir = process.argv[3] || null;
/** Where to put the skin marker: `{"orbitalDeg": o, "pixel": [x, y]}`, the pixel (of the 512 x
 * 512 image) of the skin behind the demo target in the view rotated by `o` degrees. */
const MARKER = JSON.parse(process.env.E2E_MARKER || 'null');
if (!base || !MARKER) {
  console.error('usage: E2E_MARKER={"orbitalDeg":..,"pixel":[..]} node tests/e2e.mjs <base-url> [out-dir]');
  process.exit(2);
}

/** RFC 6238 TOTP (HMAC-SHA1, 6 digits, 30 s), from a base32 secret. */
function totp(secretBase32, unixS = Date.now() / 1000) {
  const alphabet = 'ABCDEFGHIJKLMNOPQRSTUVWXYZ234567';
  let bits = '';
  for (const c of secretBase32.replace(/=+$/, '').toUpperCase()) bits += alphabet.indexOf(c).toString(2).padStart(5, '0');
  const key = Buffer.from(bits.match(/.{8}/g).map((b) => parseInt(b, 2)));
  const counter = Buffer.alloc(8);
  counter.writeBigUInt64BE(BigInt(Math.floor(unixS / 30)));
  const h = createHmac('sha1', key).update(counter).digest();
  const o = h[h.length - 1] & 0xf;
  const n = (h.readUInt32BE(o) & 0x7fffffff) % 1_000_000;
  return String(n).padStart(6, '0');
}

/** Grey-level statistics of the canvas and its 4 x 4 block means (128 x 128) for comparisons:
 * block means keep a 1 to 2 pixel needle shaft visible while averaging quantum noise down. */
async function canvasStats(page) {
  return page.evaluate(() => {
    const c = document.getElementById('fluoro');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    const n = c.width * c.height;
    let sum = 0, sum2 = 0;
    const thumb = new Array(128 * 128).fill(0);
    for (let i = 0; i < n; i++) {
      const g = d[4 * i];
      sum += g; sum2 += g * g;
      const x = ((i % c.width) * 128 / c.width) | 0, y = (Math.floor(i / c.width) * 128 / c.height) | 0;
      thumb[y * 128 + x] += g * 128 * 128 / n;
    }
    const mean = sum / n;
    return { mean, std: Math.sqrt(Math.max(0, sum2 / n - mean * mean)), thumb };
  });
}

function meanAbsDiff(a, b) {
  let s = 0;
  for (let i = 0; i < a.thumb.length; i++) s += Math.abs(a.thumb[i] - b.thumb[i]);
  return s / a.thumb.length;
}

function maxAbsDiff(a, b) {
  let m = 0;
  for (let i = 0; i < a.thumb.length; i++) m = Math.max(m, Math.abs(a.thumb[i] - b.thumb[i]));
  return m;
}

function countAbove(a, b, level) {
  let n = 0;
  for (let i = 0; i < a.thumb.length; i++) if (Math.abs(a.thumb[i] - b.thumb[i]) > level) n += 1;
  return n;
}

async function framesSoFar(page) {
  return page.evaluate(() => (window.__sim ? window.__sim.stats.frames : 0));
}

async function acksSoFar(page) {
  return page.evaluate(() => (window.__sim ? window.__sim.stats.acks : 0));
}

/** Runs `action`, then waits until a new frame arrived and every sent command was answered. */
async function act(page, action) {
  const before = await framesSoFar(page);
  await action();
  await waitUntil(page, (n) => window.__sim.stats.frames > n && window.__sim.live.pending.size === 0, before, { timeout: STEP_TIMEOUT_MS });
  // The frame event draws after decoding; wait for the draw of this frame.
  await waitUntil(page, () => Number(document.getElementById('frame-count').textContent) === window.__sim.stats.frames, null, { timeout: STEP_TIMEOUT_MS });
}

async function capture(page, name) {
  const stats = await canvasStats(page);
  if (outDir) {
    mkdirSync(outDir, { recursive: true });
    writeFileSync(join(outDir, `${name}.png`), await page.locator('#fluoro').screenshot());
  }
  return stats;
}

await runReport(async (page, report) => {

  // Learner.
  report.station = await openFirstStation(page, base);
  report.steps.push('session open');
  report.accessible = await page.evaluate(() => ({
    canvas_label: document.getElementById('fluoro').getAttribute('aria-label') || '',
    unlabeled_buttons: [...document.querySelectorAll('#session-view button')].filter((b) => !(b.textContent.trim() || b.getAttribute('aria-label'))).length,
  }));

  // Highest tube current: least quantum noise, so input-driven changes stand out clearly.
  const acksBefore = await acksSoFar(page);
  await page.fill('#ma', '20');
  await page.dispatchEvent('#ma', 'change');
  await waitUntil(page, (n) => window.__sim.stats.acks > n, acksBefore);
  await act(page, () => page.click('#shot'));
  const first = await capture(page, '1-first-shot');
  report.steps.push('shot');
  // Control: the same view again differs only by quantum noise (a new noise seed per image).
  await act(page, () => page.click('#shot'));
  const repeat = await capture(page, '1b-repeat-shot');

  // Rotate the C-arm by keyboard (20 degrees LAO) and by a mouse drag, then shoot.
  await page.focus('#fluoro');
  for (let i = 0; i < 4; i++) await page.keyboard.press('ArrowRight');
  const box = await page.locator('#fluoro').boundingBox();
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.down();
  await page.mouse.move(box.x + box.width / 2 + 40, box.y + box.height / 2, { steps: 5 });
  await page.mouse.up();
  report.orbital_deg = Number(await page.inputValue('#orbital'));
  await act(page, () => page.keyboard.press('s'));
  const rotated = await capture(page, '2-rotated');
  report.steps.push('rotated');

  // Needle: the skin marker dragged on the rotated image to the pixel where the skin behind the
  // target images (E2E_MARKER: computed by the Rust test for this pose), the C-arm back to AP
  // (slider), the puncture (down the AP central beam, +y, as the placement of the earlier
  // client), the C-arm back to the rotated pose, 55 mm advanced (the contrast transport box of
  // the demo region reaches 42 mm under its skin), shot: the rotated and needle images differ
  // by the needle only.
  const setPose = async (orbital, angular) => {
    await page.evaluate(([o, a]) => {
      for (const [id, v] of [['orbital', o], ['angular', a]]) {
        const el = document.getElementById(id);
        el.value = String(v);
        el.dispatchEvent(new Event('input', { bubbles: true }));
      }
    }, [orbital, angular]);
    // Pose commands are throttled to one per 50 ms (app.js): let the last one go, then wait for
    // its answer, so the puncture follows it.
    await page.waitForTimeout(120);
    await waitUntil(page, () => window.__sim.live.pending.size === 0);
  };
  const rotatedPose = [report.orbital_deg, Number(await page.inputValue('#angular'))];
  if (rotatedPose[0] !== MARKER.orbitalDeg || rotatedPose[1] !== 0) throw new Error(`rotated to ${rotatedPose}, the marker pixel is for ${MARKER.orbitalDeg}`);
  await page.check('input[name="drag-mode"][value="marker"]');
  await page.locator('#fluoro').scrollIntoViewIfNeeded();
  const at = await page.locator('#fluoro').boundingBox();
  const [mx, my] = [at.x + (MARKER.pixel[0] * at.width) / 512, at.y + (MARKER.pixel[1] * at.height) / 512];
  await page.mouse.move(mx - 20, my);
  await page.mouse.down();
  await page.mouse.move(mx, my, { steps: 4 });
  await page.mouse.up();
  await waitUntil(page, () => window.__sim.live.pending.size === 0);
  report.marker_text = await page.textContent('#marker-state');
  await page.check('input[name="drag-mode"][value="carm"]');
  await setPose(0, 0);
  await page.click('#puncture');
  await waitUntil(page, () => window.__sim.live.pending.size === 0);
  await setPose(...rotatedPose);
  for (let i = 0; i < 11; i++) await page.click('#feed-5');
  await waitUntil(page, () => window.__sim.live.pending.size === 0);
  report.depth_text = await page.textContent('#depth');
  report.force_text = await page.textContent('#force-text');
  await act(page, () => page.click('#shot'));
  const needle = await capture(page, '3-needle');
  report.steps.push('needle');

  // Contrast: live fluoroscopy, then hold the plunger (0.5 mL at 0.5 mL/s) for 1.2 s and
  // release; the client ticks the session clock while fluid moves and for 2 s after.
  // Pulsed fluoroscopy at 15 pulses per second for this run (the session starts at 7.5).
  if (await page.inputValue('#pps') !== '7.5') throw new Error('the pulse rate does not start at 7.5 /s');
  await page.selectOption('#pps', '15');
  await waitUntil(page, () => window.__sim.live.pending.size === 0 && window.__sim.pulseRate === 15);
  await act(page, () => page.click('#live'));
  const beforeContrast = await capture(page, '4-live-before-contrast');
  const framesBeforeInjection = await framesSoFar(page);
  // The syringe panel sits below the needle's panels: bring it on screen for the mouse.
  await page.locator('#plunger').scrollIntoViewIfNeeded();
  const plunger = await page.locator('#plunger').boundingBox();
  await page.mouse.move(plunger.x + plunger.width / 2, plunger.y + plunger.height / 2);
  await page.mouse.down();
  await page.waitForTimeout(1200);
  await page.mouse.up();
  // The ticks end 2 s after the release; then wait for the last frame and every answer.
  await page.waitForTimeout(2300);
  await waitUntil(page, () => window.__sim.live.pending.size === 0);
  await waitUntil(page, () => Number(document.getElementById('frame-count').textContent) === window.__sim.stats.frames);
  const afterContrast = await capture(page, '5-live-after-contrast');
  // The block that darkened most and its 8 neighbours (4 x 4 pixel blocks of the 128 x 128
  // thumbnail), mean grey before and after.
  let best = 0;
  for (let i = 1; i < beforeContrast.thumb.length; i++) {
    if (beforeContrast.thumb[i] - afterContrast.thumb[i] > beforeContrast.thumb[best] - afterContrast.thumb[best]) best = i;
  }
  const side = Math.round(Math.sqrt(beforeContrast.thumb.length));
  const region = (t) => {
    const [bx, by] = [best % side, Math.floor(best / side)];
    let sum = 0; let n = 0;
    for (let y = Math.max(0, by - 1); y <= Math.min(side - 1, by + 1); y++) {
      for (let x = Math.max(0, bx - 1); x <= Math.min(side - 1, bx + 1); x++) { sum += t[y * side + x]; n += 1; }
    }
    return sum / n;
  };
  report.contrast = {
    region_before: region(beforeContrast.thumb),
    region_after: region(afterContrast.thumb),
    live_frames: (await framesSoFar(page)) - framesBeforeInjection,
    injected_text: await page.textContent('#injected'),
  };
  // Live off makes no new image (last-image hold): wait for its answer only.
  await page.click('#live');
  await waitUntil(page, () => window.__sim.live.pending.size === 0);
  report.steps.push('injected');

  report.frames = {
    first: { mean: first.mean, std: first.std },
    rotated: { mean: rotated.mean, std: rotated.std },
    needle: { mean: needle.mean, std: needle.std },
    mean_diff_noise_only: meanAbsDiff(first, repeat),
    max_diff_noise_only: maxAbsDiff(first, repeat),
    mean_diff_rotation: meanAbsDiff(repeat, rotated),
    max_diff_needle: maxAbsDiff(rotated, needle),
    // Blocks changed by more than the largest noise-only change: about 1 expected from noise
    // alone (the chance that one of two equal-size noise samples holds the joint maximum).
    needle_blocks_above_noise_max: countAbove(rotated, needle, maxAbsDiff(first, repeat)),
  };
  // Collimator: the shutters closed to half the width and the iris in; the next shot shows the
  // shutters (black at the edges, the image in the middle) and the acknowledgement the field.
  const acksBeforeCollimation = await acksSoFar(page);
  await page.fill('#coll-width', '150');
  await page.dispatchEvent('#coll-width', 'change');
  await page.selectOption('#coll-iris', '230');
  await waitUntil(page, (n) => window.__sim.stats.acks >= n + 2, acksBeforeCollimation);
  await act(page, () => page.click('#shot'));
  await capture(page, '9-collimated');
  report.collimated = await page.evaluate(() => {
    const c = document.getElementById('fluoro');
    const px = (x, y) => c.getContext('2d').getImageData(x, y, 1, 1).data[0];
    return {
      field: window.__sim.collimation,
      left_edge: px(Math.round(c.width * 0.05), Math.round(c.height / 2)),
      right_edge: px(Math.round(c.width * 0.95), Math.round(c.height / 2)),
      centre: px(Math.round(c.width / 2), Math.round(c.height / 2)),
      corner: px(Math.round(c.width * 0.3), Math.round(c.height * 0.05)),
      width_readout: document.getElementById('coll-width-out').textContent,
    };
  });
  report.steps.push('collimated');
  // Magnification: mag 2 halves the field; the acknowledgement names it.
  const acksBeforeMag = await acksSoFar(page);
  await page.selectOption('#field', '0.5');
  await waitUntil(page, (n) => window.__sim.stats.acks > n, acksBeforeMag);
  report.magnified_field_mm = await page.evaluate(() => window.__sim.fieldMm);
  // The brightness curve and the recursive filter from the page: the acknowledgements say so.
  const acksBeforeCurve = await acksSoFar(page);
  await page.selectOption('#abc', 'low_dose');
  await page.selectOption('#recursive-filter', 'high');
  await page.selectOption('#grid', 'out');
  await waitUntil(page, (n) => window.__sim.stats.acks >= n + 3, acksBeforeCurve);
  report.curve_and_filter = await page.evaluate(() => ({
    brightness: window.__sim.technique && window.__sim.technique.brightness,
    filter: window.__sim.recursiveFilter,
    grid: window.__sim.grid,
    detector: window.__sim.detector,
  }));
  report.readout = { latency: await page.textContent('#latency'), fps: await page.textContent('#fps') };
  report.command_errors = await page.evaluate(() => window.__sim.stats.errors);
  report.session_log = await page.textContent('#session-log');

  await page.click('#submit');
  await page.waitForSelector('#result:not([hidden])');
  report.result_text = (await page.textContent('#result')).replace(/\s+/g, ' ').trim();
  report.acks = await acksSoFar(page);
  report.steps.push('submitted');
  await page.click('#logout');
  await page.waitForSelector('#login-view:not([hidden])');

  // Faculty.
  await login(page, 'faculty@demo.invalid');
  await page.waitForSelector('#faculty-view:not([hidden])');
  if (await page.isVisible('#totp-enroll')) {
    await page.click('#totp-enroll');
    await page.waitForSelector('#totp-secret-box:not([hidden])');
    const secret = (await page.textContent('#totp-secret')).trim();
    await page.fill('#totp-confirm-code', totp(secret));
    await page.click('#totp-confirm');
    await page.waitForSelector('#totp-setup[hidden]', { state: 'attached' });
    report.steps.push('totp');
  }
  await page.waitForSelector('#queue tbody button');
  report.queue_rows = await page.locator('#queue tbody tr').count();
  await page.locator('#queue tbody button').first().click();
  await page.waitForSelector('#review:not([hidden])');
  await waitUntil(page, () => document.getElementById('replay-check').textContent.length > 0);
  report.replay_check = await page.textContent('#replay-check');
  await waitUntil(page, () => document.getElementById('review-provenance').textContent.length > 0);
  report.provenance = await page.textContent('#review-provenance');
  report.queue_provenance = await page.textContent('#queue tbody tr td:nth-child(5)');
  report.timeline_steps = await page.locator('#timeline-list li').count();
  await waitUntil(page, () => { const i = document.getElementById('replay-frame'); return i.complete && i.naturalWidth > 0; });
  report.replay_frame_width = await page.evaluate(() => document.getElementById('replay-frame').naturalWidth);
  await page.fill('#review-comment', 'Approved in the end-to-end test.');
  await page.click('#approve');
  await waitUntil(page, () => document.getElementById('message').textContent === 'Approved.');
  report.steps.push('approved');
});
