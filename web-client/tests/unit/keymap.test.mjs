// The fluoroscopy key map (web-client/keymap.js): defaults, remapping, conflicts refused, and
// the stored map's fallbacks. Run: node --test web-client/tests/unit/
import { test } from 'node:test';
import assert from 'node:assert/strict';
import * as keymap from '../../keymap.js';

/** A localStorage stand-in. */
function memoryStorage(initial = {}) {
  const m = new Map(Object.entries(initial));
  return {
    getItem: (k) => (m.has(k) ? m.get(k) : null),
    setItem: (k, v) => m.set(k, String(v)),
    removeItem: (k) => m.delete(k),
  };
}

test('the defaults are the PACS viewer keys, with the C-arm and needle on free keys', () => {
  const k = keymap.defaultKeys();
  assert.equal(keymap.problem(k), null);
  assert.equal(k.reset, 'Space');
  assert.equal(k.invert, 'i');
  assert.equal(k.flipH, 'h');
  assert.equal(k.flipV, 'v');
  assert.equal(k.zoomIn, '+');
  assert.equal(k.zoomOut, '-');
  assert.equal(k.cancel, 'Escape');
  assert.equal(k.help, '?');
  assert.equal(k.shot, 'x');
  assert.equal(k.carmLao, 'Ctrl+ArrowRight');
  assert.equal(Object.keys(k).length, keymap.ACTIONS.length);
});

test('events map to keys: letters in lower case, Shift left out, other modifiers kept', () => {
  assert.equal(keymap.eventKey({ key: 'X', shiftKey: true }), 'x');
  assert.equal(keymap.eventKey({ key: ' ' }), 'Space');
  assert.equal(keymap.eventKey({ key: '?', shiftKey: true }), '?');
  assert.equal(keymap.eventKey({ key: 'ArrowRight', ctrlKey: true, shiftKey: true }), 'Ctrl+ArrowRight');
  assert.equal(keymap.eventKey({ key: 'i', ctrlKey: true }), 'Ctrl+i');
  assert.equal(keymap.eventKey({ key: 'Shift', shiftKey: true }), null);
  const k = keymap.defaultKeys();
  assert.equal(keymap.actionFor(k, 'x'), 'shot');
  // A modifier makes it another key: Ctrl+I is not invert (it stays the browser's).
  assert.equal(keymap.actionFor(k, 'Ctrl+i'), null);
  assert.equal(keymap.actionFor(k, null), null);
});

test('a remap moves an action to a free key and is stored', () => {
  const storage = memoryStorage();
  const r = keymap.remap(keymap.defaultKeys(), 'shot', 'g');
  assert.equal(r.error, undefined);
  assert.equal(r.keys.shot, 'g');
  assert.equal(keymap.actionFor(r.keys, 'x'), null);
  assert.deepEqual(keymap.save(storage, r.keys), { keys: r.keys });
  assert.equal(JSON.parse(storage.getItem(keymap.STORAGE_KEY)).version, 1);
  assert.equal(keymap.load(storage).shot, 'g');
});

test('a key another action has is refused with a message, the map unchanged', () => {
  const k = keymap.defaultKeys();
  const r = keymap.remap(k, 'shot', 'i');
  assert.match(r.error, /already "Invert grey levels"/);
  assert.equal(r.keys, undefined);
  assert.equal(k.shot, 'x');
  assert.match(keymap.remap(k, 'nope', 'q').error, /unknown action/);
  assert.match(keymap.remap(k, 'shot', null).error, /cannot be used/);
  // Saving a conflicting map is refused too.
  const storage = memoryStorage();
  assert.match(keymap.save(storage, { ...k, shot: 'i' }).error, /already/);
  assert.equal(storage.getItem(keymap.STORAGE_KEY), null);
});

test('what is stored falls back to the defaults when it is not a valid map', () => {
  const d = keymap.defaultKeys();
  assert.deepEqual(keymap.load(memoryStorage()), d);
  for (const bad of ['{not json', 'null', '42', '"x"', JSON.stringify({ version: 2, keys: { shot: 'g' } }),
    JSON.stringify({ version: 1 }), JSON.stringify({ version: 1, keys: { ...d, shot: 'i' } })]) {
    assert.deepEqual(keymap.load(memoryStorage({ [keymap.STORAGE_KEY]: bad })), d, bad);
  }
  // A map stored before an action existed: the action gets its default key.
  const older = { ...d, shot: 'g' };
  delete older.aspirate;
  assert.deepEqual(keymap.load(memoryStorage({ [keymap.STORAGE_KEY]: JSON.stringify({ version: 1, keys: older }) })), { ...d, shot: 'g' });
  // A storage that throws (private mode) is no map either.
  assert.deepEqual(keymap.load({ getItem: () => { throw new Error('denied'); } }), d);
});

test('key labels', () => {
  assert.equal(keymap.keyLabel('Ctrl+ArrowRight'), 'Ctrl + →');
  assert.equal(keymap.keyLabel('x'), 'X');
  assert.equal(keymap.keyLabel('+'), '+');
  assert.equal(keymap.keyLabel('Escape'), 'Esc');
});
