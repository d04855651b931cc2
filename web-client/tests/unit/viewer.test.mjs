// The viewer transform and look-up table (web-client/viewer.js).
import { test } from 'node:test';
import assert from 'node:assert/strict';
import * as v from '../../viewer.js';

const IMAGE = [512, 512];
const CANVAS = [512, 512];
const close = (a, b, eps = 1e-9) => assert.ok(Math.abs(a - b) < eps, `${a} vs ${b}`);

test('the default view maps every pixel onto itself and leaves grey levels alone', () => {
  const view = v.defaultView();
  assert.deepEqual(v.imageToCanvas(view, IMAGE, CANVAS, [10, 300]), [10, 300]);
  const t = v.lut(view.window, view.level, view.invert);
  for (let g = 0; g < 256; g++) assert.equal(t[g], g);
  assert.ok(v.isIdentityLut(view));
});

test('pixel mapping round trips under zoom, pan and flips', () => {
  let view = v.defaultView();
  view = v.zoomBy(view, 2);
  view = v.panBy(view, 37, -11);
  for (const flips of [[false, false], [true, false], [false, true], [true, true]]) {
    const w = { ...view, flipH: flips[0], flipV: flips[1] };
    for (const p of [[0, 0], [511.5, 3.25], [256, 256], [100, 400]]) {
      const c = v.imageToCanvas(w, IMAGE, CANVAS, p);
      const back = v.canvasToImage(w, IMAGE, CANVAS, c);
      close(back[0], p[0]);
      close(back[1], p[1]);
    }
  }
  // Zoom 2 about the centre: the centre stays, a pixel 10 right of it lands 20 right.
  const z = v.zoomBy(v.defaultView(), 2);
  assert.deepEqual(v.imageToCanvas(z, IMAGE, CANVAS, [256, 256]), [256, 256]);
  assert.deepEqual(v.imageToCanvas(z, IMAGE, CANVAS, [266, 256]), [276, 256]);
  // A horizontal flip puts the image's left column at the canvas's right.
  const f = { ...v.defaultView(), flipH: true };
  assert.deepEqual(v.imageToCanvas(f, IMAGE, CANVAS, [0, 5]), [512, 5]);
  assert.deepEqual(v.screenToImageDirection(f, 1, 1), [-1, 1]);
  // A smaller image is fitted: a 256-pixel frame fills the 512-pixel canvas.
  assert.deepEqual(v.imageToCanvas(v.defaultView(), [256, 256], CANVAS, [128, 64]), [256, 128]);
});

test('zoom keeps the pan proportional and stays within its limits', () => {
  const p = v.panBy(v.defaultView(), 10, 20);
  const z = v.zoomBy(p, 2);
  assert.deepEqual(z.pan, [20, 40]);
  assert.equal(v.zoomBy(v.defaultView(), 1000).zoom, v.MAX_ZOOM);
  assert.equal(v.zoomBy(v.defaultView(), 1e-6).zoom, v.MIN_ZOOM);
  assert.ok(v.zoomDrag(v.defaultView(), -100).zoom > 1, 'an upward right drag zooms in');
});

test('window/level drag and the look-up table', () => {
  const start = v.defaultView();
  const narrow = v.windowLevelDrag(start, -155, 0);
  assert.equal(narrow.window, 100);
  assert.equal(narrow.level, start.level);
  const t = v.lut(100, 127.5, false);
  assert.equal(t[0], 0);
  assert.equal(t[77], 0);
  assert.equal(t[178], 255);
  assert.equal(t[255], 255);
  assert.ok(t[120] > 100 && t[120] < 128);
  const inv = v.lut(255, 127.5, true);
  assert.equal(inv[0], 255);
  assert.equal(inv[255], 0);
  assert.equal(v.windowLevelDrag(start, -10000, 0).window, v.MIN_WINDOW);
  assert.equal(v.windowLevelDrag(start, 0, 20).level, 147.5);
  const data = new Uint8ClampedArray([10, 10, 10, 255, 200, 200, 200, 7]);
  v.applyLut(data, inv);
  assert.deepEqual([...data], [245, 245, 245, 255, 55, 55, 55, 7]);
});
