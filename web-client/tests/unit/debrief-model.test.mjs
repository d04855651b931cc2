// The debrief's words and drawing (web-client/debrief-model.js): values, tolerances, outcomes,
// and the reveal's outline runs as rectangles.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import * as m from '../../debrief-model.js';

test('values read as the server explains them', () => {
  assert.equal(m.showValue(2.345, 'mm'), '2.3 mm');
  assert.equal(m.showValue(12.04, 'deg'), '12.0°');
  assert.equal(m.showValue(0.857, 'fraction'), '86 %');
  assert.equal(m.showValue(1, 'bool'), 'yes');
  assert.equal(m.showValue(0, 'bool'), 'no');
  assert.equal(m.showValue(3, 'count'), '3');
  assert.equal(m.showValue(0.1234, 'mgy'), '0.12 mGy');
  assert.equal(m.showValue(0.01234, 'gycm2'), '0.012 Gy·cm²');
  assert.equal(m.showValue(null, 'mm'), 'not measured');
});

test('each tolerance law in words', () => {
  assert.equal(m.toleranceWords({ law: 'lower_is_better', pass_within: 2, fail_beyond: 5 }, 'mm'),
    'full credit at or below 2.0 mm; none from 5.0 mm');
  assert.equal(m.toleranceWords({ law: 'near_value', value: 25, pass_within: 5, fail_beyond: 15 }, 'deg'),
    'ideal 25.0°; full credit within 5.0° of it, none from 15.0° away');
  assert.equal(m.toleranceWords({ law: 'higher_is_better', pass_from: 0.9, fail_below: 0.5 }, 'fraction'),
    'full credit from 90 %; none at or below 50 %');
  assert.equal(m.toleranceWords({ law: 'boolean', expected: true }, 'bool'), 'expected: yes');
  assert.equal(m.toleranceWords(null, 'mm'), 'no tolerance stated');
});

test('outcomes and statuses in neutral words; failed safety criteria found', () => {
  assert.equal(m.outcomeWords('met'), 'Met');
  assert.equal(m.outcomeWords('not_met'), 'Not met');
  assert.equal(m.outcomeWords('incomplete'), 'Incomplete');
  assert.equal(m.outcomeWords(null), 'No result');
  assert.equal(m.statusWords('missing'), 'Not measured');
  assert.equal(m.scoreWords(0.754), '75 %');
  assert.equal(m.structureWords('dural_sac'), 'dural sac');
  const criteria = [
    { id: 'a', critical: true, status: 'met' },
    { id: 'b', critical: true, status: 'not_met' },
    { id: 'c', critical: false, status: 'not_met' },
    { id: 'd', critical: true, status: 'missing' },
  ];
  assert.deepEqual(m.failedSafety(criteria).map((c) => c.id), ['b']);
});

test('outline runs become one rectangle per run, scaled and grown', () => {
  const runs = [[10, 4, 8], [11, 4, 4], [12, 9, 3]];
  assert.deepEqual(m.outlineRects(runs), [{ x: 4, y: 10, w: 5, h: 1 }, { x: 4, y: 11, w: 1, h: 1 }]);
  assert.deepEqual(m.outlineRects([[10, 4, 8]], 2), [{ x: 8, y: 20, w: 10, h: 2 }]);
  assert.deepEqual(m.outlineRects([[10, 4, 8]], 1, 1), [{ x: 3, y: 9, w: 7, h: 3 }]);
  // Half scale: the rectangle still covers the run's pixels and is never empty.
  assert.deepEqual(m.outlineRects([[11, 5, 5]], 0.5), [{ x: 2, y: 5, w: 1, h: 1 }]);
});

test('colours follow the order the needle entered the structures; envelopes stay in the legend', () => {
  const reveal = {
    width: 512, height: 512,
    touched: ['skin', 'ligamentum_flavum', 'epidural_space'],
    outlines: [
      { structure: 'epidural_space', runs: [[100, 200, 210]] },
      { structure: 'ligamentum_flavum', runs: [[90, 200, 205], [91, 200, 200]] },
    ],
  };
  const d = m.revealDrawing(reveal, 512, 0);
  assert.deepEqual(d.layers.map((l) => l.structure), ['ligamentum_flavum', 'epidural_space']);
  assert.equal(d.colours.get('skin'), m.OUTLINE_COLOURS[0]);
  assert.equal(d.layers[0].colour, m.OUTLINE_COLOURS[1]);
  assert.equal(d.layers[1].colour, m.OUTLINE_COLOURS[2]);
  assert.equal(d.layers[0].rects.length, 2);
  assert.deepEqual(d.unoutlined, ['skin']);
  // No outline colour is a grey, so no pixel of the radiograph under it can match it.
  for (const c of m.OUTLINE_COLOURS) {
    const [r, g, b] = m.rgb(c);
    assert.ok(Math.max(r, g, b) - Math.min(r, g, b) > 60, c);
  }
  assert.equal(new Set(m.OUTLINE_COLOURS).size, m.OUTLINE_COLOURS.length);
});
