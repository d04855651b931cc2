// End-to-end run of the ultrasound station in headless Chromium (see harness.mjs): a learner
// opens the station, sets depth, gain, TGC and frequency with the controls, drags the probe on
// the placement view, slides it with the keyboard (the speckle check), brings it over the
// target, places the needle in the scan plane and advances it, freezes and unfreezes, and
// submits.
//
// Each probe move is drawn first as a draft with its "Preview" badge, then as the full frame
// (`preview` in the report).
//
// Usage: node tests/e2e_ultrasound.mjs <base-url> [out-dir]
// Prints one JSON object on stdout (the figures the Rust test asserts on) and exits 0 when every
// step passed, 1 with {"ok": false, "error": ...} otherwise. Canvas captures go to out-dir.

import { writeFileSync, mkdirSync } from 'node:fs';
import { join } from 'node:path';
import { waitUntil, openFirstStation, runReport } from './harness.mjs';

const base = process.argv[2];
const outDir = process.argv[3] || null;
if (!base) {
  console.error('usage: node tests/e2e_ultrasound.mjs <base-url> [out-dir]');
  process.exit(2);
}

const sub = (a, b) => a.map((v, i) => v - b[i]);
const dot = (a, b) => a.reduce((s, v, i) => s + v * b[i], 0);
const norm = (a) => { const l = Math.hypot(...a) || 1; return a.map((v) => v / l); };
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];

/** Waits until every sent command was answered and a drawn frame of `view` reflects the newest
 * of them (`minSeq`: an earlier sequence number, for commands that do not change the view). */
async function settle(page, view = 'ultrasound', minSeq = null) {
  // Key steps are summed for up to 50 ms before they are sent (see ultrasound.js).
  await waitUntil(page, () => !window.__sim.us.moveTimer && !window.__sim.us.pendingMove && window.__sim.live.pending.size === 0);
  // A state query (sent after each needle command and on connecting) changes no view: the
  // frame to wait for reflects the command before it.
  const seq = minSeq ?? await page.evaluate(() => {
    const s = window.__sim.live.seq;
    return s === window.__sim.us.lastQuerySeq ? s - 1 : s;
  });
  // The full frame: a draft (a preview while the probe moves) of the same input comes first.
  await waitUntil(page, ([v, s]) => { const d = window.__sim.us.drawn[v]; return !!d && d.inputSeq >= s && !d.draft; }, [view, seq]);
  // All received frames decoded and drawn (the frame counter counts draws).
  await waitUntil(page, () => Number(document.getElementById('frame-count').textContent) === window.__sim.stats.frames);
}

/** Grey levels of the B-mode image itself (the canvas without its scale margins), kept in the
 * page as window.__caps[name]; returns its size and grey-level statistics, and saves the
 * canvases to out-dir. */
async function capture(page, name) {
  const stats = await page.evaluate((n) => {
    const us = window.__sim.us;
    const f = us.bitmapFrame;
    const m = us.margin;
    const c = document.getElementById('bmode');
    const d = c.getContext('2d').getImageData(m.left, m.top, f.width, f.height).data;
    const grey = new Float32Array(f.width * f.height);
    let sum = 0; let sum2 = 0;
    for (let i = 0; i < grey.length; i++) { const g = d[4 * i]; grey[i] = g; sum += g; sum2 += g * g; }
    window.__caps = window.__caps || {};
    window.__caps[n] = { w: f.width, h: f.height, grey };
    const mean = sum / grey.length;
    return { width: f.width, height: f.height, mean, std: Math.sqrt(Math.max(0, sum2 / grey.length - mean * mean)), canvas_width: c.width, canvas_height: c.height };
  }, name);
  if (outDir) {
    mkdirSync(outDir, { recursive: true });
    writeFileSync(join(outDir, `${name}-bmode.png`), await page.locator('#bmode').screenshot());
    writeFileSync(join(outDir, `${name}-placement.png`), await page.locator('#placement').screenshot());
  }
  return stats;
}

/** Normalized cross-correlation of captures `a` and `b` over the central half of `a` (columns
 * and rows from a quarter to three quarters, as the render-worker test), pairing a[x, y] with
 * b[x + dx, y + dy]. With `rowDemeaned`, each row's mean (over the compared columns, per image)
 * is subtracted first: the brightness profile over depth (attenuation, gain, TGC) is the same
 * in every frame whatever the probe's position, so it correlates at every shift and would hide
 * whether the speckle itself moved; without it the figure is the plain NCC. */
function ncc(page, a, b, dx, dy, rowDemeaned = false) {
  return page.evaluate(([a, b, dx, dy, rowDemeaned]) => {
    const A = window.__caps[a]; const B = window.__caps[b];
    const { w, h } = A;
    const x0 = Math.max(w >> 2, -dx); const x1 = Math.min((3 * w) >> 2, w - dx);
    let sa = 0; let sb = 0; let saa = 0; let sbb = 0; let sab = 0; let n = 0;
    for (let y = h >> 2; y < (3 * h) >> 2; y++) {
      const y2 = y + dy;
      if (y2 < 0 || y2 >= h || x1 <= x0) continue;
      let ma = 0; let mb = 0;
      if (rowDemeaned) {
        for (let x = x0; x < x1; x++) { ma += A.grey[y * w + x]; mb += B.grey[y2 * w + x + dx]; }
        ma /= x1 - x0; mb /= x1 - x0;
      }
      for (let x = x0; x < x1; x++) {
        const p = A.grey[y * w + x] - ma; const q = B.grey[y2 * w + x + dx] - mb;
        sa += p; sb += q; saa += p * p; sbb += q * q; sab += p * q; n += 1;
      }
    }
    const cov = sab / n - (sa / n) * (sb / n);
    return cov / Math.sqrt((saa / n - (sa / n) ** 2) * (sbb / n - (sb / n) ** 2));
  }, [a, b, dx, dy, rowDemeaned]);
}

/** 4 x 4 pixel blocks whose mean grey rose by more than `level` from capture `a` to `b`. */
function brighterBlocks(page, a, b, level) {
  return page.evaluate(([a, b, level]) => {
    const A = window.__caps[a]; const B = window.__caps[b];
    let count = 0;
    for (let by = 0; by + 4 <= A.h; by += 4) {
      for (let bx = 0; bx + 4 <= A.w; bx += 4) {
        let d = 0;
        for (let y = by; y < by + 4; y++) for (let x = bx; x < bx + 4; x++) d += B.grey[y * A.w + x] - A.grey[y * A.w + x];
        if (d / 16 > level) count += 1;
      }
    }
    return count;
  }, [a, b, level]);
}

function sameCapture(page, a, b) {
  return page.evaluate(([a, b]) => {
    const A = window.__caps[a].grey; const B = window.__caps[b].grey;
    return A.length === B.length && A.every((v, i) => v === B[i]);
  }, [a, b]);
}

const outcome = (page) => page.evaluate(() => window.__sim.us.outcome);

/** Sets a range input as a person would (the readout follows on `input`, the command goes on
 * `change`). */
async function setSlider(page, id, value) {
  await page.$eval(`#${id}`, (el, v) => {
    el.value = String(v);
    el.dispatchEvent(new Event('input', { bubbles: true }));
    el.dispatchEvent(new Event('change', { bubbles: true }));
  }, value);
}

/** Presses `key` `n` times on the focused element. */
async function press(page, key, n) {
  for (let i = 0; i < n; i++) await page.keyboard.press(key);
}

await runReport(async (page, report) => {
  report.station = await openFirstStation(page, base);
  // Every change of the B-mode "Preview" badge's visibility, recorded as it happens (a draft
  // shows for tens of milliseconds before the full frame of the same input).
  await page.evaluate(() => {
    window.__usBadge = [];
    const el = document.getElementById('us-draft');
    new MutationObserver(() => window.__usBadge.push(el.hidden ? 'hidden' : 'shown'))
      .observe(el, { attributes: true, attributeFilter: ['hidden'] });
  });
  // The client asks for the probe's state right after connecting; both views arrive.
  await waitUntil(page, () => !!(window.__sim.us.outcome && window.__sim.us.drawn.placement));
  await settle(page);
  report.views = await page.evaluate(() => window.__sim.views);
  report.steps.push('session open');
  report.accessible = await page.evaluate(() => ({
    bmode_label: document.getElementById('bmode').getAttribute('aria-label') || '',
    placement_label: document.getElementById('placement').getAttribute('aria-label') || '',
    ultrasound_visible: !document.getElementById('us-station').hidden,
    unlabeled_buttons: [...document.querySelectorAll('#session-view button')].filter((b) => !(b.textContent.trim() || b.getAttribute('aria-label'))).length,
    unlabeled_inputs: [...document.querySelectorAll('#session-view input, #session-view select')]
      .filter((i) => !((i.labels && i.labels.length) || i.getAttribute('aria-label') || i.getAttribute('aria-labelledby'))).length,
    keys_help: document.getElementById('us-keys').textContent.replace(/\s+/g, ' ').trim(),
  }));
  const frames = { first: await capture(page, '1-first') };
  frames.placement = await page.evaluate(() => {
    const c = document.getElementById('placement');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let sum = 0; let sum2 = 0; const n = c.width * c.height;
    for (let i = 0; i < n; i++) { const g = d[4 * i]; sum += g; sum2 += g * g; }
    const mean = sum / n;
    return { width: c.width, height: c.height, mean, std: Math.sqrt(Math.max(0, sum2 / n - mean * mean)) };
  });

  // The station has fluoroscopy too: a shot's frame goes to the fluoroscopy canvas and leaves
  // the ultrasound views alone.
  const usFrames = await page.evaluate(() => window.__sim.us.drawn.ultrasound.frames);
  await page.click('#shot');
  await waitUntil(page, () => (window.__sim.stats.views.fluoroscopy || { frames: 0 }).frames > 0 && window.__sim.live.pending.size === 0);
  await waitUntil(page, () => Number(document.getElementById('frame-count').textContent) === window.__sim.stats.frames);
  report.shot = await page.evaluate((before) => {
    const c = document.getElementById('fluoro');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let sum = 0; let sum2 = 0; const n = c.width * c.height;
    for (let i = 0; i < n; i++) { const g = d[4 * i]; sum += g; sum2 += g * g; }
    const mean = sum / n;
    return { std: Math.sqrt(Math.max(0, sum2 / n - mean * mean)), ultrasound_frames_unchanged: window.__sim.us.drawn.ultrasound.frames === before };
  }, usFrames);
  if (outDir) writeFileSync(join(outDir, '1a-shot-fluoro.png'), await page.locator('#fluoro').screenshot());

  // Probe select from the tray: the linear probe (10 to 90 mm, 5 to 12 MHz) and back to the
  // curvilinear one (its defaults again: 10 cm).
  await page.selectOption('#us-probe', 'linear-probe');
  await settle(page);
  const linear = await outcome(page);
  report.linear = {
    probe: linear.probe,
    depth_max: await page.getAttribute('#us-depth', 'max'),
    frequency_text: await page.textContent('#us-frequency-out'),
    width: (await capture(page, '1b-linear')).width,
  };
  await page.selectOption('#us-probe', 'curvilinear-probe');
  await settle(page);
  report.curvilinear_depth_mm = (await outcome(page)).settings.depth_mm;

  // Scanner controls: 2 cm deeper with the depth button (10 to 12 cm on the curvilinear
  // probe), gain, the deepest TGC band, focus and frequency with their sliders.
  await page.click('#us-depth-more');
  await page.click('#us-depth-more');
  await settle(page);
  await setSlider(page, 'us-gain', 24);
  await setSlider(page, 'us-tgc-5', 6);
  await setSlider(page, 'us-focus', 70);
  await setSlider(page, 'us-frequency', 3);
  await settle(page);
  const o1 = await outcome(page);
  report.settings = o1.settings;
  report.image = o1.image;
  report.depth_label = await page.textContent('#us-depth-out');
  report.steps.push('settings');

  // Drag the probe on the placement view: press at the centre, move 40 px right.
  await page.focus('#placement');
  const box = await page.locator('#placement').boundingBox();
  const before = (await outcome(page)).position_mm;
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.down();
  await page.mouse.move(box.x + box.width / 2 + 40, box.y + box.height / 2, { steps: 5 });
  await page.mouse.up();
  await settle(page);
  const dragged = await outcome(page);
  report.drag = { before_mm: before, after_mm: dragged.position_mm, moved_mm: Math.hypot(...sub(dragged.position_mm, before)) };
  // A touch drag (touch events through the DevTools protocol, as a finger on a touch screen):
  // 30 px back to the left.
  const cdp = await page.context().newCDPSession(page);
  const touch = (type, dx) => cdp.send('Input.dispatchTouchEvent', {
    type, touchPoints: type === 'touchEnd' ? [] : [{ x: box.x + box.width / 2 + dx, y: box.y + box.height / 2 }],
  });
  await touch('touchStart', 40);
  for (const dx of [30, 20, 10]) await touch('touchMove', dx);
  await touch('touchEnd', 10);
  await settle(page);
  const touched = await outcome(page);
  report.drag.touch_moved_mm = Math.hypot(...sub(touched.position_mm, dragged.position_mm));
  frames.dragged = await capture(page, '2-dragged');
  report.steps.push('dragged');

  // Over the target: slide along the marker and across the slice by the keyboard (Ctrl+arrow
  // 5 mm, arrow 1 mm) until the face centre is above it (within half a step).
  // The target's position comes from the Rust test (E2E_US_TARGET_MM): the station the learner's
  // browser gets lists its targets without positions.
  const target = process.env.E2E_US_TARGET_MM
    ? JSON.parse(process.env.E2E_US_TARGET_MM)
    : await page.evaluate(() => window.__sim.station.targets[0].position_mm);
  let offsets = null;
  for (let round = 0; round < 4; round++) {
    const o = await outcome(page);
    const marker = norm(o.marker_dir);
    const beam = norm(o.beam_dir);
    const elevation = cross(marker.map((v) => -v), beam);
    const d = sub(target, o.position_mm);
    offsets = { along_marker_mm: dot(d, marker), across_mm: dot(d, elevation) };
    if (Math.abs(offsets.along_marker_mm) < 0.5 && Math.abs(offsets.across_mm) < 0.5) break;
    for (const [mm, plus, minus] of [[offsets.along_marker_mm, 'ArrowLeft', 'ArrowRight'], [offsets.across_mm, 'ArrowUp', 'ArrowDown']]) {
      const key = mm > 0 ? plus : minus;
      const big = Math.trunc(Math.abs(mm) / 5);
      await press(page, `Control+${key}`, big);
      await press(page, key, Math.round(Math.abs(mm) - 5 * big));
    }
    await settle(page);
  }
  const over = await outcome(page);
  report.target = {
    target_mm: target,
    probe_mm: over.position_mm,
    lateral_offset_mm: Math.abs(offsets.along_marker_mm),
    elevation_offset_mm: Math.abs(offsets.across_mm),
    depth_below_face_mm: dot(sub(target, over.position_mm), norm(over.beam_dir)),
  };
  frames.over_target = await capture(page, '3-over-target');
  report.steps.push('over target');

  // Speckle moves with the probe: slide 3 mm towards the marker with the arrow key (1 mm a
  // press). The tissue then appears 3 mm further from the marker side: the old image's column
  // x is the new image's column x + 3 / pixel_mm (rows unchanged: the skin is flat). Over the
  // target the whole compared region (the central half) lies inside the scannable crop.
  await page.focus('#bmode');
  const slideMm = 3;
  await press(page, 'ArrowLeft', slideMm);
  await settle(page);
  await capture(page, '4-slid');
  const pixelMm = (await outcome(page)).image.pixel_mm;
  const predicted = Math.round(slideMm / pixelMm);
  let shifted = -1; let bestDy = 0;
  for (let dy = -3; dy <= 3; dy++) {
    const v = await ncc(page, '3-over-target', '4-slid', predicted, dy, true);
    if (v > shifted) { shifted = v; bestDy = dy; }
  }
  let bestDx = 0; let bestDxNcc = -1;
  for (let dx = -4; dx <= predicted + 6; dx++) {
    const v = await ncc(page, '3-over-target', '4-slid', dx, bestDy, true);
    if (v > bestDxNcc) { bestDxNcc = v; bestDx = dx; }
  }
  // Back by the same 3 mm: the same tissue under the same pose gives the same image (the
  // speckle belongs to the tissue, fixed per session).
  await press(page, 'ArrowRight', slideMm);
  await settle(page);
  await capture(page, '5-back');
  report.speckle = {
    slide_mm: slideMm,
    pixel_mm: pixelMm,
    predicted_dx_px: predicted,
    best_dy_px: bestDy,
    ncc_shifted: shifted,
    ncc_unshifted: await ncc(page, '3-over-target', '4-slid', 0, 0, true),
    plain_ncc_shifted: await ncc(page, '3-over-target', '4-slid', predicted, bestDy),
    plain_ncc_unshifted: await ncc(page, '3-over-target', '4-slid', 0, 0),
    best_dx_px: bestDx,
    ncc_best_dx: bestDxNcc,
    back_identical: await sameCapture(page, '3-over-target', '5-back'),
  };
  report.steps.push('speckle');


  // Needle in plane: from beyond the end of the probe away from the marker, aimed at 40 mm
  // under the face, advanced 30 mm with the Needle buttons.
  await page.fill('#us-needle-aim', '40');
  await page.click('#us-needle-place');
  for (let i = 0; i < 6; i++) await page.click('#feed-5');
  await settle(page);
  const n = await outcome(page);
  report.needle = {
    tip_in_slice: n.tip_in_slice,
    needle_in_slice: n.needle_in_slice,
    feedback: await page.textContent('#us-feedback'),
    depth_text: await page.textContent('#depth'),
  };
  frames.needle = await capture(page, '6-needle');
  // The same pose and settings without and with the needle: the speckle is the tissue's, so
  // only the needle (and its shadow) changes the image. Blocks brighter by 30 grey levels are
  // the shaft's specular echo (speckle alone does not change at all).
  report.needle.bright_blocks = await brighterBlocks(page, '3-over-target', '6-needle', 30);
  if (outDir) writeFileSync(join(outDir, '6-needle-page.png'), await page.screenshot({ fullPage: true }));
  report.steps.push('needle in plane');

  // Freeze holds the image while the needle moves 1 mm; unfreeze shows it live again.
  await page.click('#us-freeze');
  await settle(page);
  await capture(page, '7-frozen');
  const placed = await page.evaluate(() => window.__sim.us.drawn.placement.frames);
  await page.click('#feed-1');
  await waitUntil(page, () => window.__sim.live.pending.size === 0);
  await waitUntil(page, (p) => window.__sim.us.drawn.placement.frames > p, placed);
  await waitUntil(page, () => Number(document.getElementById('frame-count').textContent) === window.__sim.stats.frames);
  await capture(page, '8-frozen-after-feed');
  report.freeze = {
    frozen: (await outcome(page)).frozen,
    frozen_text: await page.textContent('#us-frozen'),
    held: await sameCapture(page, '7-frozen', '8-frozen-after-feed'),
  };
  await page.click('#us-freeze');
  await settle(page);
  report.freeze.unfrozen_tip_in_slice = (await outcome(page)).tip_in_slice;
  report.steps.push('frozen');

  // Rock (Shift+Left: 2 degrees in the scan plane), rotate (Q: 5 degrees about the beam), and
  // back (E, then Shift+Right): each an exact inverse about the same axis.
  // Signed: a direction turned over (180 degrees) reads as 180, not as 0 as it would from |dot|.
  const angle = (a, b) => (Math.acos(Math.max(-1, Math.min(1, dot(norm(a), norm(b))))) * 180) / Math.PI;
  await page.focus('#bmode');
  const p0 = await outcome(page);
  await page.keyboard.press('Shift+ArrowLeft');
  await settle(page);
  const p1 = await outcome(page);
  await page.keyboard.press('q');
  await settle(page);
  const p2 = await outcome(page);
  await page.keyboard.press('e');
  await settle(page);
  await page.keyboard.press('Shift+ArrowRight');
  await settle(page);
  const p3 = await outcome(page);
  report.tilt = {
    rock_deg: angle(p0.beam_dir, p1.beam_dir),
    rock_marker_deg: angle(p0.marker_dir, p1.marker_dir),
    rotate_deg: angle(p1.marker_dir, p2.marker_dir),
    rotate_beam_deg: angle(p1.beam_dir, p2.beam_dir),
    back_beam_deg: angle(p0.beam_dir, p3.beam_dir),
    back_marker_deg: angle(p0.marker_dir, p3.marker_dir),
    back_tip_in_slice: p3.tip_in_slice,
  };
  report.steps.push('tilted');

  report.frames = frames;
  report.preview = await page.evaluate(() => ({
    drafts: window.__sim.stats.views.ultrasound.drafts,
    frames: window.__sim.stats.views.ultrasound.frames,
    badge: window.__usBadge,
    last_drawn_draft: window.__sim.us.drawn.ultrasound.draft,
    badge_hidden: document.getElementById('us-draft').hidden,
  }));
  report.command_errors = await page.evaluate(() => window.__sim.stats.errors);
  report.session_log = await page.textContent('#session-log');
  await page.click('#submit');
  await page.waitForSelector('#result:not([hidden])');
  report.result_text = (await page.textContent('#result')).replace(/\s+/g, ' ').trim();
  report.acks = await page.evaluate(() => window.__sim.stats.acks);
  report.steps.push('submitted');
});
