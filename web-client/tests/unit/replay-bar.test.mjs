// The replay bar's logic (web-client/replay-bar.js): speeds, tick positions, announcements and
// the one-at-a-time frame loader.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import * as r from '../../replay-bar.js';

const EVENTS = [
  { step: 2, seq: 2, t_ms: 1500, kind: 'image', label: 'Shot' },
  { step: 5, seq: 5, t_ms: 9000, kind: 'puncture', label: 'Skin puncture (spinal-22g)' },
  { step: 9, seq: 9, t_ms: 20000, kind: 'loss_of_resistance', label: 'Loss of resistance' },
  { step: 9, seq: 9, t_ms: 20000, kind: 'bone_contact', label: 'Bone contact' },
  { step: 20, seq: 20, t_ms: 95000, kind: 'submit', label: 'Submitted' },
];

test('each speed divides the base pause: 0.5x doubles it, 4x quarters it', () => {
  assert.deepEqual(r.SPEEDS, [0.5, 1, 2, 4]);
  assert.equal(r.stepInterval(1), r.BASE_STEP_MS);
  assert.equal(r.stepInterval(0.5), 2 * r.BASE_STEP_MS);
  assert.equal(r.stepInterval(2), r.BASE_STEP_MS / 2);
  assert.equal(r.stepInterval('4'), r.BASE_STEP_MS / 4);
  assert.throws(() => r.stepInterval(0), RangeError);
  assert.throws(() => r.stepInterval('fast'), RangeError);
});

test('ticks sit at step / steps along the bar, one per event, stacked at a shared step', () => {
  const t = r.tickLayout(EVENTS, 20);
  assert.equal(t.length, EVENTS.length);
  assert.deepEqual(t.map((x) => x.fraction), [0.1, 0.25, 0.45, 0.45, 1]);
  assert.deepEqual(t.map((x) => x.row), [0, 0, 0, 1, 0]);
  assert.deepEqual(t.map((x) => x.kind), EVENTS.map((e) => e.kind));
  // Out-of-range steps are clamped onto the bar; an empty log does not divide by zero.
  assert.deepEqual(r.tickLayout([{ step: 30, kind: 'image' }, { step: -1, kind: 'image' }], 20).map((x) => x.fraction), [1, 0]);
  assert.equal(r.tickLayout([{ step: 0, kind: 'submit' }], 0)[0].fraction, 0);
});

test('a tick lines up with the range thumb: inset by half a thumb at both ends', () => {
  assert.equal(r.tickLeft(0), `calc(${r.THUMB_INSET_PX}px + 0 * (100% - ${2 * r.THUMB_INSET_PX}px))`);
  assert.match(r.tickLeft(0.5), /0\.5 \* \(100% - 16px\)/);
});

test('every event kind has its own colour and shape; an unknown kind still draws', () => {
  const kinds = ['image', 'puncture', 'loss_of_resistance', 'injection', 'bone_contact', 'violation', 'submit'];
  const styles = kinds.map((k) => r.eventStyle(k));
  assert.equal(new Set(styles.map((s) => s.colour)).size, kinds.length);
  assert.equal(new Set(styles.map((s) => s.shape)).size, kinds.length);
  for (const s of styles) assert.match(s.path, /^M[\d .A-Z-]+Z$/);
  assert.equal(r.eventStyle('new_kind').name, 'new_kind');
});

test('announcements name the position and the events of that step', () => {
  assert.equal(r.announcement(EVENTS, 9, 20), 'Step 9 of 20: Loss of resistance; Bone contact.');
  assert.equal(r.announcement(EVENTS, 3, 20), 'Step 3 of 20.');
  assert.equal(r.announcement(EVENTS, 0, 20), 'Start (step 0 of 20).');
  assert.equal(r.eventText(EVENTS[1]), 'Step 5, 9.0 s: Skin puncture (spinal-22g)');
  assert.equal(r.clock(125_000), '2 min 05 s');
});

test('neighbouring events and clamped steps', () => {
  assert.equal(r.neighbourEventStep(EVENTS, 2, 1), 5);
  assert.equal(r.neighbourEventStep(EVENTS, 9, -1), 5);
  assert.equal(r.neighbourEventStep(EVENTS, 20, 1), null);
  assert.equal(r.neighbourEventStep(EVENTS, 2, -1), null);
  assert.equal(r.clampStep(-3, 20), 0);
  assert.equal(r.clampStep(25, 20), 20);
  assert.equal(r.clampStep('7', 20), 7);
});

/** A fetch whose answers the test releases by hand. */
function manualFetch() {
  const pending = [];
  const fetchFrame = (step) => new Promise((resolve, reject) => pending.push({ step, resolve, reject }));
  return { pending, fetchFrame };
}
const flush = () => new Promise((res) => setTimeout(res, 0));

test('the frame loader keeps one request in flight and skips stale steps', async () => {
  const { pending, fetchFrame } = manualFetch();
  const shown = [];
  const loader = new r.FrameLoader(fetchFrame, (step, frame) => shown.push([step, frame]));
  loader.request(1);
  await flush();
  for (const k of [2, 3, 4, 5]) loader.request(k);
  await flush();
  assert.equal(pending.length, 1, 'one request in flight');
  assert.equal(loader.idle, false);
  pending[0].resolve('frame-1');
  await flush();
  await flush();
  // Step 1 is stale (5 is wanted): dropped; 2, 3 and 4 were never fetched.
  assert.deepEqual(shown, []);
  assert.deepEqual(loader.fetched, [1, 5]);
  assert.equal(pending.length, 2);
  const idle = loader.whenIdle();
  pending[1].resolve('frame-5');
  await idle;
  assert.deepEqual(shown, [[5, 'frame-5']]);
  assert.equal(loader.idle, true);
});

test('the frame loader shows "no image" frames, reports failures and asks again for the same step only once', async () => {
  const { pending, fetchFrame } = manualFetch();
  const shown = [];
  const failed = [];
  const loader = new r.FrameLoader(fetchFrame, (step, frame) => shown.push([step, frame]), (step, e) => failed.push([step, e.message]));
  loader.request(0);
  loader.request(0);
  await flush();
  assert.equal(pending.length, 1);
  pending[0].resolve(null);
  await loader.whenIdle();
  assert.deepEqual(shown, [[0, null]]);
  loader.request(3);
  await flush();
  pending[1].reject(new Error('HTTP 500'));
  await loader.whenIdle();
  assert.deepEqual(failed, [[3, 'HTTP 500']]);
  assert.deepEqual(loader.fetched, [0, 3]);
});
