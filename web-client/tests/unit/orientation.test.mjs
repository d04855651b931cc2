// The overlays' geometry (web-client/orientation.js): orientation letters, the view's name, the
// scale bar, and hub tilts that follow the screen.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import * as o from '../../orientation.js';

const AP = { orbital: 0, angular: 0 };

test("letters in AP: the patient's right on the screen's left, head up", () => {
  assert.deepEqual(o.edgeLetters(AP), { left: 'R', right: 'L', top: 'H', bottom: 'F' });
});

test('letters follow the flips', () => {
  assert.deepEqual(o.edgeLetters(AP, { flipH: true }), { left: 'L', right: 'R', top: 'H', bottom: 'F' });
  assert.deepEqual(o.edgeLetters(AP, { flipV: true }), { left: 'R', right: 'L', top: 'F', bottom: 'H' });
  assert.deepEqual(o.edgeLetters(AP, { flipH: true, flipV: true }), { left: 'L', right: 'R', top: 'F', bottom: 'H' });
});

test('letters in LAO 90 (lateral), RAO 45 and cranial 30', () => {
  // LAO 90: screen-right u = (0, -1, 0) is posterior.
  assert.deepEqual(o.edgeLetters({ orbital: 90, angular: 0 }), { left: 'A', right: 'P', top: 'H', bottom: 'F' });
  assert.deepEqual(o.edgeLetters({ orbital: 90, angular: 0 }, { flipH: true }), { left: 'P', right: 'A', top: 'H', bottom: 'F' });
  // RAO 45: u = (-0.71, 0.71, 0): left and anterior, left first (equal weights keep R/L first).
  assert.deepEqual(o.edgeLetters({ orbital: -45, angular: 0 }), { left: 'RP', right: 'LA', top: 'H', bottom: 'F' });
  // Cranial 30: up = cos 30 z - sin 30 y: head and posterior.
  assert.deepEqual(o.edgeLetters({ orbital: 0, angular: 30 }), { left: 'R', right: 'L', top: 'HP', bottom: 'FA' });
  assert.deepEqual(o.edgeLetters({ orbital: 0, angular: 30 }, { flipV: true }), { left: 'R', right: 'L', top: 'FA', bottom: 'HP' });
  // A small oblique keeps one letter (sin 20 degrees = 0.34 is under the 22.5 degree cut).
  assert.equal(o.edgeLetters({ orbital: 20, angular: 0 }).right, 'L');
});

test('view names', () => {
  assert.equal(o.viewName(AP), 'AP');
  assert.equal(o.viewName({ orbital: 30, angular: 0 }), 'LAO 30°');
  assert.equal(o.viewName({ orbital: -20, angular: 0 }), 'RAO 20°');
  assert.equal(o.viewName({ orbital: 90, angular: 0 }), 'lateral');
  assert.equal(o.viewName({ orbital: 0, angular: 15 }), 'AP cranial 15°');
  assert.equal(o.viewName({ orbital: -45, angular: -10 }), 'RAO 45° caudal 10°');
});

test('the scale bar: isocentre pixel size, and its length doubles with the zoom', () => {
  // 300 mm over 512 pixels at the detector, magnification 1480 / 730.
  const pitch = o.isocentrePixelMm({ fieldMm: 300, imagePx: 512 });
  assert.ok(Math.abs(pitch - (300 / 512) * (730 / 1480)) < 1e-12);
  const z1 = o.scaleBar({ fieldMm: 300, imagePx: 512, canvasPx: 512, zoom: 1 });
  assert.equal(z1.mm, 50);
  assert.ok(Math.abs(z1.canvasPx - 50 / pitch) < 1e-9);
  assert.ok(z1.fraction <= o.SCALE_MAX_FRACTION);
  const z2 = o.scaleBar({ fieldMm: 300, imagePx: 512, canvasPx: 512, zoom: 2 });
  assert.equal(z2.mm, 20);
  // Pixels per millimetre double with the zoom.
  assert.ok(Math.abs(z2.canvasPx / z2.mm - (2 * z1.canvasPx) / z1.mm) < 1e-9);
  // Mag 2 (a 150 mm field) shows the anatomy twice as large as the full field.
  const mag = o.scaleBar({ fieldMm: 150, imagePx: 512, canvasPx: 512, zoom: 1 });
  assert.ok(Math.abs(mag.canvasPx / mag.mm - (2 * z1.canvasPx) / z1.mm) < 1e-9);
  // Distances from the hello replace the defaults.
  const near = o.scaleBar({ fieldMm: 300, imagePx: 512, canvasPx: 512, zoom: 1, sidMm: 1000, sodMm: 500 });
  assert.ok(Math.abs(near.canvasPx / near.mm - (512 / 300) * 2) < 1e-9);
});

test('hub tilts follow the screen: AP and lateral', () => {
  // AP: screen-right aims towards the patient's left, up cranially.
  assert.deepEqual(o.screenToTilt(AP, 2, 0), { cc: 0, ml: 2 });
  assert.deepEqual(o.screenToTilt(AP, 0, 2), { cc: 2, ml: 0 });
  // Lateral (LAO 90): screen-right is posterior: no medio-lateral tilt; up is still cranial.
  assert.deepEqual(o.screenToTilt({ orbital: 90, angular: 0 }, 2, 0), { cc: 0, ml: 0 });
  assert.deepEqual(o.screenToTilt({ orbital: 90, angular: 0 }, 0, 2), { cc: 2, ml: 0 });
  // RAO 90: the same.
  assert.deepEqual(o.screenToTilt({ orbital: -90, angular: 0 }, 2, 0), { cc: 0, ml: 0 });
  // LAO 60: half of a screen-right drag is medio-lateral.
  const t = o.screenToTilt({ orbital: 60, angular: 0 }, 2, 0);
  assert.ok(Math.abs(t.ml - 1) < 1e-9 && t.cc === 0, JSON.stringify(t));
});
