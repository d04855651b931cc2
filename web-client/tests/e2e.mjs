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

/** The viewer's state, overlays and a few canvas figures (grey levels of the middle row). */
async function viewerState(page) {
  return page.evaluate(() => {
    const s = window.__sim.screen;
    const c = document.getElementById('fluoro');
    const row = [...c.getContext('2d').getImageData(0, c.height / 2, c.width, 1).data].filter((_, i) => i % 4 === 0);
    const text = (id) => document.getElementById(id).textContent;
    const bar = document.getElementById('scale-bar');
    return {
      view: JSON.parse(JSON.stringify(s.view)),
      letters: { left: text('orient-left'), right: text('orient-right'), top: text('orient-top'), bottom: text('orient-bottom') },
      corners: { view: text('corner-view'), technique: text('corner-technique'), dose: text('corner-dose'), zoom: text('corner-zoom') },
      scale: { hidden: bar.hidden, mm: Number(bar.dataset.mm), fraction: Number(bar.dataset.fraction), css_width: bar.getBoundingClientRect().width },
      row,
    };
  });
}

const rowStd = (row) => {
  const m = row.reduce((a, b) => a + b, 0) / row.length;
  return Math.sqrt(row.reduce((a, b) => a + (b - m) * (b - m), 0) / row.length);
};
const maxRowDiff = (a, b) => Math.max(...a.map((v, i) => Math.abs(v - b[i])));

/** Window/level, invert, flip, zoom, pan, escape and reset on the last image, by the mouse and
 * by keys pressed with the focus on the page's body; then the C-arm to LAO 90 and a shot. */
async function viewerChecks(page) {
  const out = {};
  // Every answer in and the last frame drawn, so the image holds still while it is measured.
  await waitUntil(page, () => window.__sim.live.pending.size === 0);
  await waitUntil(page, () => Number(document.getElementById('frame-count').textContent) === window.__sim.stats.frames);
  const framesAtStart = await framesSoFar(page);
  await page.check('input[name="drag-mode"][value="view"]');
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  out.focus = await page.evaluate(() => document.activeElement.tagName);
  await page.locator('#fluoro').scrollIntoViewIfNeeded();
  const box = await page.locator('#fluoro').boundingBox();
  const [cx, cy] = [box.x + box.width / 2, box.y + box.height / 2];
  const before = await viewerState(page);
  out.before = { ...before, row: undefined };
  // Window/level: a left drag 150 px left narrows the window (more contrast).
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  await page.mouse.move(cx - 150, cy, { steps: 5 });
  await page.mouse.up();
  const wl = await viewerState(page);
  // The look-up table of the new window and level (viewer.js `lut`), applied to the row as it
  // was: the drawn row must be exactly that.
  const lower = wl.view.level - wl.view.window / 2;
  const expected = before.row.map((g) => Math.round(Math.max(0, Math.min(255, (255 * (g - lower)) / wl.view.window))));
  out.wl = {
    view: wl.view, corner: wl.corners.zoom, std_before: rowStd(before.row), std_after: rowStd(wl.row),
    max_diff: maxRowDiff(before.row, wl.row), lut_error: maxRowDiff(expected, wl.row),
  };
  // Escape during a drag puts the window/level back where the drag started.
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  await page.mouse.move(cx, cy + 60, { steps: 3 });
  await page.keyboard.press('Escape');
  await page.mouse.move(cx, cy + 90, { steps: 2 });
  await page.mouse.up();
  out.escape = { level_after: (await viewerState(page)).view.level, level_before: wl.view.level };
  // Space resets everything: the canvas is the frame as decoded again.
  await page.keyboard.press(' ');
  const reset = await viewerState(page);
  out.reset = { view: reset.view, max_diff: maxRowDiff(before.row, reset.row) };
  // Invert: every grey level g becomes 255 - g.
  await page.keyboard.press('i');
  const inv = await viewerState(page);
  out.invert = { view_invert: inv.view.invert, max_error: Math.max(...before.row.map((g, i) => Math.abs(255 - g - inv.row[i]))) };
  await page.keyboard.press('i');
  // Flip: the row mirrored, and the letters of the left and right edges swapped.
  await page.keyboard.press('h');
  const flip = await viewerState(page);
  out.flip = {
    letters_before: before.letters, letters_after: flip.letters,
    max_error: Math.max(...before.row.map((g, i) => Math.abs(g - flip.row[before.row.length - 1 - i]))),
  };
  await page.keyboard.press('h');
  // Zoom: `+` and a right drag up; the scale bar grows with it.
  await page.keyboard.press('+');
  const z1 = await viewerState(page);
  await page.mouse.move(cx, cy);
  await page.mouse.down({ button: 'right' });
  await page.mouse.move(cx, cy - 100, { steps: 4 });
  await page.mouse.up({ button: 'right' });
  const z2 = await viewerState(page);
  out.zoom = {
    key: z1.view.zoom, drag: z2.view.zoom, corner: z2.corners.zoom,
    scale_before: before.scale, scale_key: z1.scale, changed: maxRowDiff(before.row, z1.row),
  };
  // Pan: a middle drag 40 px right moves the image 40 CSS px right.
  await page.mouse.move(cx, cy);
  await page.mouse.down({ button: 'middle' });
  await page.mouse.move(cx + 40, cy, { steps: 4 });
  await page.mouse.up({ button: 'middle' });
  const pan = await viewerState(page);
  out.pan = { pan: pan.view.pan, css_per_canvas_px: box.width / 512 };
  // The skin marker cursor, if shown, and a marker pixel under a pointer follow the view: the
  // pixel under the canvas centre is the image point the zoom and pan put there.
  out.pixel_at_centre = await page.evaluate(([x, y]) => window.__sim.screen.pixelAt({ x, y }), [cx, cy]);
  await page.keyboard.press(' ');
  out.after_reset = (await viewerState(page)).view;
  // No frame came while the view was measured (the rows compared are of one image).
  out.frames_during = (await framesSoFar(page)) - framesAtStart;
  // The C-arm to LAO 90 by keys, a shot: the letters are those of a lateral view.
  for (let i = 0; i < 12; i++) await page.keyboard.press('Control+ArrowRight');
  await page.waitForTimeout(120);
  await waitUntil(page, () => window.__sim.live.pending.size === 0);
  await act(page, () => page.keyboard.press('x'));
  const lateral = await viewerState(page);
  out.lateral = { orbital: Number(await page.inputValue('#orbital')), letters: lateral.letters, corners: lateral.corners };
  await page.keyboard.press('h');
  out.lateral.flipped = (await viewerState(page)).letters;
  await page.keyboard.press(' ');
  // Hub keys follow the screen: in the lateral view screen-right is posterior, which no hub
  // tilt can aim at (no command), while up is still cranial (one 1 degree tilt).
  await page.check('input[name="drag-mode"][value="hub"]');
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  const seq = () => page.evaluate(() => window.__sim.live.seq);
  const settleTilt = () => waitUntil(page, () => !window.__sim.needle.tiltThrottle.timer && !window.__sim.needle.tilt && window.__sim.live.pending.size === 0);
  const s0 = await seq();
  await page.keyboard.press('ArrowRight');
  await page.waitForTimeout(120);
  await settleTilt();
  const s1 = await seq();
  await page.keyboard.press('Shift+ArrowUp');
  await settleTilt();
  out.lateral.hub_commands = { right: s1 - s0, up: (await seq()) - s1 };
  await page.check('input[name="drag-mode"][value="view"]');
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  out.layout = await layoutChecks(page);
  return out;
}

/** The session screen's layout at 1440 x 900 (the image beside the controls, at least 60 % of
 * the width), at 1024 x 768 (no sideways scrolling) and at a tablet's 800 x 1200 (the image the whole width, the controls below), the
 * light and dark themes, and the focus ring; the viewport is put back afterwards. */
async function layoutChecks(page) {
  const measure = () => page.evaluate(() => {
    const f = document.getElementById('fluoro').getBoundingClientRect();
    const c = document.querySelector('#session-view .controls').getBoundingClientRect();
    return { viewport: innerWidth, content: document.documentElement.clientWidth, scroll_width: document.documentElement.scrollWidth, image_width: f.width, image_right: f.right, image_bottom: f.bottom, controls_left: c.left, controls_top: c.top };
  });
  const out = {};
  const original = page.viewportSize();
  await page.setViewportSize({ width: 1440, height: 900 });
  out.desktop = await measure();
  if (outDir) await page.screenshot({ path: join(outDir, 'layout-1440x900.png') });
  await page.setViewportSize({ width: 1024, height: 768 });
  out.small = await measure();
  if (outDir) await page.screenshot({ path: join(outDir, 'layout-1024x768.png') });
  await page.setViewportSize({ width: 800, height: 1200 });
  out.tablet = await measure();
  if (outDir) await page.screenshot({ path: join(outDir, 'layout-800x1200.png') });
  await page.setViewportSize(original);
  const bg = () => page.evaluate(() => getComputedStyle(document.body).backgroundColor);
  await page.emulateMedia({ colorScheme: 'light' });
  out.light_bg = await bg();
  await page.emulateMedia({ colorScheme: 'dark' });
  out.dark_bg = await bg();
  await page.emulateMedia({ colorScheme: null });
  // A control reached by the keyboard shows its focus ring.
  await page.focus('#shot');
  await page.keyboard.press('Shift+Tab');
  await page.keyboard.press('Tab');
  out.focus_outline = await page.evaluate(() => {
    const s = getComputedStyle(document.activeElement);
    return { id: document.activeElement.id, style: s.outlineStyle, width: s.outlineWidth };
  });
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  return out;
}

/** `?` opens the key map; a remap is refused on a taken key and kept on a free one; the new key
 * shoots. */
async function keymapChecks(page) {
  const out = {};
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  await page.keyboard.press('?');
  out.opened = await page.evaluate(() => {
    const d = document.getElementById('keymap-dialog');
    return { open: d.open, heading: d.querySelector('h2').textContent, rows: d.querySelectorAll('tbody tr').length };
  });
  // A key another action has: refused, with the reason.
  await page.click('#keymap-rows button[data-action="shot"]');
  await page.keyboard.press('i');
  out.conflict = await page.textContent('#keymap-message');
  // Escape while a key is awaited cancels the change and leaves the dialog open.
  await page.click('#keymap-rows button[data-action="shot"]');
  await page.keyboard.press('Escape');
  out.escape_capture = await page.evaluate(() => ({ open: document.getElementById('keymap-dialog').open, message: document.getElementById('keymap-message').textContent }));
  // A free key: taken.
  await page.click('#keymap-rows button[data-action="shot"]');
  await page.keyboard.press('g');
  out.remapped = await page.textContent('#keymap-message');
  out.help_shot = await page.textContent('#fluoro-keys kbd[data-action="shot"]');
  await page.keyboard.press('Escape');
  out.closed = await page.evaluate(() => !document.getElementById('keymap-dialog').open);
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  const shots = await page.evaluate(() => window.__sim.screen.info.acquisitions);
  await act(page, () => page.keyboard.press('g'));
  await waitUntil(page, () => window.__sim.live.pending.size === 0);
  out.shots = [shots, await page.evaluate(() => window.__sim.screen.info.acquisitions)];
  return out;
}

await runReport(async (page, report) => {

  // Learner.
  report.station = await openFirstStation(page, base);
  report.steps.push('session open');
  report.accessible = await page.evaluate(() => ({
    canvas_label: document.getElementById('fluoro').getAttribute('aria-label') || '',
    unlabeled_buttons: [...document.querySelectorAll('#session-view button')].filter((b) => !(b.textContent.trim() || b.getAttribute('aria-label'))).length,
  }));

  // Before the first image: the canvas says how to get one (never a silent black image).
  report.first_image_wait = { before: await page.evaluate(() => ({
    shown: !document.getElementById('fluoro-wait').hidden,
    text: document.getElementById('fluoro-wait').textContent,
  })) };

  // Highest tube current: least quantum noise, so input-driven changes stand out clearly.
  const acksBefore = await acksSoFar(page);
  await page.fill('#ma', '20');
  await page.dispatchEvent('#ma', 'change');
  await waitUntil(page, (n) => window.__sim.stats.acks > n, acksBefore);
  await act(page, () => page.click('#shot'));
  const first = await capture(page, '1-first-shot');
  report.steps.push('shot');
  report.first_image_wait.after_hidden = await page.evaluate(() => document.getElementById('fluoro-wait').hidden);
  // Store the AP image in the strip by key (focus on the page, no click on the image).
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  await page.keyboard.press('s');
  await waitUntil(page, () => document.querySelectorAll('#stored-images li').length === 1);
  // Control: the same view again differs only by quantum noise (a new noise seed per image).
  await act(page, () => page.click('#shot'));
  const repeat = await capture(page, '1b-repeat-shot');

  // Rotate the C-arm by keyboard (20 degrees LAO, Ctrl + arrow, with the focus on the page's
  // body: the keys need no click on the image) and by its buttons (10 more), then shoot by key.
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  report.focus_for_keys = await page.evaluate(() => document.activeElement.tagName);
  for (let i = 0; i < 4; i++) await page.keyboard.press('Control+ArrowRight');
  for (let i = 0; i < 2; i++) await page.click('#carm-lao');
  report.orbital_deg = Number(await page.inputValue('#orbital'));
  await page.evaluate(() => document.activeElement && document.activeElement.blur());
  await act(page, () => page.keyboard.press('x'));
  const rotated = await capture(page, '2-rotated');
  report.steps.push('rotated');
  report.announced_after_shot = await page.textContent('#announcer');
  // Store the oblique too, then show the AP as the reference beside it.
  await page.keyboard.press('s');
  await waitUntil(page, () => document.querySelectorAll('#stored-images li').length === 2);
  await page.click('#stored-images li:first-child button');
  report.stored = await page.evaluate(() => ({
    count: document.querySelectorAll('#stored-images li').length,
    labels: [...document.querySelectorAll('#stored-images button')].map((b) => b.getAttribute('aria-label')),
    reference_shown: !document.getElementById('reference-image').hidden,
    reference_src_blob: (document.getElementById('reference-image').getAttribute('src') || '').startsWith('blob:'),
    reference_alt: document.getElementById('reference-image').alt,
    pressed: [...document.querySelectorAll('#stored-images button')].map((b) => b.getAttribute('aria-pressed')),
  }));
  report.steps.push('stored');

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
  await page.check('input[name="drag-mode"][value="view"]');
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

  report.viewer = await viewerChecks(page);
  report.steps.push('viewer');
  report.keymap = await keymapChecks(page);
  report.steps.push('keymap');

  await page.click('#submit');
  await page.waitForSelector('#result:not([hidden])');
  report.result_text = (await page.textContent('#result')).replace(/\s+/g, ' ').trim();
  report.acks = await acksSoFar(page);
  report.steps.push('submitted');
  // The remapped key survives a reload (the learner's home page loads the key map too).
  await page.reload();
  await page.waitForSelector('#learner-view:not([hidden])');
  report.keymap.after_reload = await page.evaluate(() => ({
    help_shot: document.querySelector('#fluoro-keys kbd[data-action="shot"]').textContent,
    shot_shortcut: document.getElementById('shot').getAttribute('aria-keyshortcuts'),
    stored: localStorage.getItem('painsim.fluoro-keymap.v1'),
  }));
  report.steps.push('reloaded');
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
