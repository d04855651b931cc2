// The fluoroscopy screen's key map: one key per action, the defaults (viewer keys as in OHIF /
// Cornerstone, so a PACS user's hands work), the learner's remapping stored in localStorage, and
// matching keyboard events to actions. Pure functions: `storage` is passed in (localStorage in
// the page, a stub in web-client/tests/unit/keymap.test.mjs), nothing here touches the DOM.
//
// A key is written as the event's `key` (letters in lower case, the space bar as "Space"),
// prefixed by "Ctrl+", "Alt+" and "Meta+" when those are held. Shift is not part of a key: it
// chooses the fine step of the actions that have one (and it is already in the character of
// keys like "?" and "+").

/** Where the map is stored; the version is in the name, so a future format starts afresh
 * rather than misreading this one (simulator choice). */
export const STORAGE_KEY = 'painsim.fluoro-keymap.v1';

/** Every action with its default key, its group and its words in the key help. Defaults:
 * W/L, zoom, pan, invert, flips, reset and escape as in OHIF's viewer (`space` reset, `i`
 * invert, `h` / `v` flips, `+` / `-` zoom, `esc` cancel); the C-arm and the needle on keys
 * those leave free (simulator choice). */
export const ACTIONS = [
  { id: 'help', key: '?', group: 'View', label: 'Show this key map' },
  { id: 'reset', key: 'Space', group: 'View', label: 'Reset the view (window/level, zoom, pan, invert, flips)' },
  { id: 'invert', key: 'i', group: 'View', label: 'Invert grey levels' },
  { id: 'flipH', key: 'h', group: 'View', label: 'Flip horizontally' },
  { id: 'flipV', key: 'v', group: 'View', label: 'Flip vertically' },
  { id: 'zoomIn', key: '+', group: 'View', label: 'Zoom in' },
  { id: 'zoomOut', key: '-', group: 'View', label: 'Zoom out' },
  { id: 'cancel', key: 'Escape', group: 'View', label: 'Cancel a drag or close a dialog' },
  { id: 'store', key: 's', group: 'View', label: 'Store the image on screen in the strip (choose one there as the reference)' },
  { id: 'modeView', key: '1', group: 'Pointer', label: 'Left drag adjusts window/level; arrows pan' },
  { id: 'modeMarker', key: '2', group: 'Pointer', label: 'Left drag and arrows move the skin marker' },
  { id: 'modeHub', key: '3', group: 'Pointer', label: 'Left drag and arrows tilt the needle hub' },
  { id: 'nudgeUp', key: 'ArrowUp', group: 'Pointer', label: 'Up: pan, marker 4 px, hub 2° (Shift: 1)' },
  { id: 'nudgeDown', key: 'ArrowDown', group: 'Pointer', label: 'Down: pan, marker, hub' },
  { id: 'nudgeLeft', key: 'ArrowLeft', group: 'Pointer', label: 'Left: pan, marker, hub' },
  { id: 'nudgeRight', key: 'ArrowRight', group: 'Pointer', label: 'Right: pan, marker, hub' },
  { id: 'shot', key: 'x', group: 'C-arm', label: 'Take a shot' },
  { id: 'carmLao', key: 'Ctrl+ArrowRight', group: 'C-arm', label: 'Rotate towards LAO 5° (Shift: 1°)' },
  { id: 'carmRao', key: 'Ctrl+ArrowLeft', group: 'C-arm', label: 'Rotate towards RAO 5° (Shift: 1°)' },
  { id: 'carmCranial', key: 'Ctrl+ArrowUp', group: 'C-arm', label: 'Tilt cranial 5° (Shift: 1°)' },
  { id: 'carmCaudal', key: 'Ctrl+ArrowDown', group: 'C-arm', label: 'Tilt caudal 5° (Shift: 1°)' },
  { id: 'puncture', key: 'p', group: 'Needle', label: 'Puncture at the skin marker' },
  { id: 'feed', key: 'f', group: 'Needle', label: 'Advance 1 mm (Shift: 0.5 mm)' },
  { id: 'withdraw', key: 'w', group: 'Needle', label: 'Withdraw 1 mm (Shift: 0.5 mm)' },
  { id: 'roll', key: 'r', group: 'Needle', label: 'Roll the needle 90°' },
  { id: 'aspirate', key: 'a', group: 'Needle', label: 'Aspirate' },
];

/** The default map: action id -> key. */
export function defaultKeys() {
  return Object.fromEntries(ACTIONS.map((a) => [a.id, a.key]));
}

/** The key of a keyboard event (`{ key, ctrlKey, altKey, metaKey }`), or null for a modifier
 * pressed alone. */
export function eventKey(e) {
  if (['Shift', 'Control', 'Alt', 'Meta', 'AltGraph', 'CapsLock', 'Dead', 'Unidentified'].includes(e.key)) return null;
  const base = e.key === ' ' ? 'Space' : e.key.length === 1 ? e.key.toLowerCase() : e.key;
  return `${e.ctrlKey ? 'Ctrl+' : ''}${e.altKey ? 'Alt+' : ''}${e.metaKey ? 'Meta+' : ''}${base}`;
}

/** A key as the key help shows it. */
export function keyLabel(key) {
  const names = { ArrowUp: '↑', ArrowDown: '↓', ArrowLeft: '←', ArrowRight: '→', Escape: 'Esc', Space: 'Space' };
  const mods = [];
  let base = key;
  for (let m = /^(Ctrl|Alt|Meta)\+(.+)$/.exec(base); m; m = /^(Ctrl|Alt|Meta)\+(.+)$/.exec(base)) { mods.push(m[1]); base = m[2]; }
  return [...mods, names[base] || (base.length === 1 ? base.toUpperCase() : base)].join(' + ');
}

/** The action `keys` binds to `key`, or null. */
export function actionFor(keys, key) {
  if (!key) return null;
  const hit = ACTIONS.find((a) => keys[a.id] === key);
  return hit ? hit.id : null;
}

/** Why `keys` cannot be used (two actions on one key, an action without a key, an unknown
 * action), or null when it can. */
export function problem(keys) {
  const seen = new Map();
  for (const a of ACTIONS) {
    const k = keys[a.id];
    if (typeof k !== 'string' || k === '') return `${a.label} has no key`;
    if (seen.has(k)) return `${keyLabel(k)} is already "${seen.get(k).label}"`;
    seen.set(k, a);
  }
  const unknown = Object.keys(keys).find((id) => !ACTIONS.some((a) => a.id === id));
  return unknown ? `unknown action ${unknown}` : null;
}

/** `keys` with `action` on `key`: `{ keys }` (a new map), or `{ error }` when another action
 * already has that key (the map is then unchanged) or the key cannot be bound. */
export function remap(keys, action, key) {
  if (!ACTIONS.some((a) => a.id === action)) return { error: `unknown action ${action}` };
  if (!key) return { error: 'that key cannot be used' };
  const other = ACTIONS.find((a) => a.id !== action && keys[a.id] === key);
  if (other) return { error: `${keyLabel(key)} is already "${other.label}": change that one first` };
  return { keys: { ...keys, [action]: key } };
}

/** The stored map, or the defaults when nothing is stored or what is stored is not a valid map
 * of this version (bad JSON, a conflict, a missing action). Actions added since it was stored
 * get their default key unless that key is taken. */
export function load(storage) {
  let stored;
  try {
    stored = JSON.parse(storage.getItem(STORAGE_KEY));
  } catch {
    return defaultKeys();
  }
  if (!stored || typeof stored !== 'object' || stored.version !== 1 || !stored.keys || typeof stored.keys !== 'object') return defaultKeys();
  const keys = {};
  for (const a of ACTIONS) {
    const k = stored.keys[a.id];
    keys[a.id] = typeof k === 'string' && k !== '' ? k : null;
  }
  const taken = new Set(Object.values(keys).filter(Boolean));
  for (const a of ACTIONS) if (keys[a.id] == null && !taken.has(a.key)) { keys[a.id] = a.key; taken.add(a.key); }
  return problem(keys) ? defaultKeys() : keys;
}

/** Stores `keys` (refused, with the reason, when they conflict). */
export function save(storage, keys) {
  const why = problem(keys);
  if (why) return { error: why };
  storage.setItem(STORAGE_KEY, JSON.stringify({ version: 1, keys }));
  return { keys };
}
