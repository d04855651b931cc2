import { test } from 'node:test';
import assert from 'node:assert/strict';

import { MAX_STORED, pushBounded, storedLabel } from '../../image-store.js';

test('labels give the number, the view and the minutes and seconds', () => {
  assert.equal(storedLabel(3, 'LAO 30°', 134_400), 'Image 3: LAO 30°, stored at 02:14');
  assert.equal(storedLabel(1, 'AP', 0), 'Image 1: AP, stored at 00:00');
});

test('the strip keeps the newest images and hands back the ones it drops', () => {
  const items = [];
  const dropped = [];
  for (let i = 1; i <= MAX_STORED + 2; i += 1) dropped.push(...pushBounded(items, i));
  assert.equal(items.length, MAX_STORED);
  assert.deepEqual(dropped, [1, 2]);
  assert.equal(items[0], 3);
  assert.equal(items.at(-1), MAX_STORED + 2);
});
