// The fluoroscopy image on screen, with a PACS user's hands (OHIF / Cornerstone conventions):
// window/level by left drag (in the default "view" mode), zoom by right drag or the keys, pan by
// middle drag, invert, flips and reset; the keys of the key map work anywhere on the page (not
// in form fields), and `?` opens the key map to remap them. Overlays are HTML over the image,
// never burned into its pixels: orientation letters, a millimetre scale at the isocentre, and
// the view, technique, dose and zoom in the corners.
//
// The arithmetic lives in modules without the DOM (viewer.js, orientation.js, keymap.js, tested
// by node); this module draws, listens and writes the page.

import {
  defaultView, transform, canvasToImage, imageToCanvas, screenToImageDirection, lut, isIdentityLut,
  applyLut, windowLevelDrag, zoomBy, zoomDrag, panBy, ZOOM_STEP,
} from './viewer.js';
import { edgeLetters, viewName, scaleBar, screenToTilt, SOURCE_TO_DETECTOR_MM, SOURCE_TO_ISOCENTRE_MM } from './orientation.js';
import * as keymap from './keymap.js';
import { ImageStore } from './image-store.js';

const $ = (id) => document.getElementById(id);

/** Pan per arrow key in the view mode, canvas pixels (simulator choice: 1/32 of the 512-pixel
 * canvas; 1/4 of that with Shift). */
const PAN_KEY_PX = 16;
const PAN_FINE_PX = 4;
/** C-arm rotation per key, degrees: 5, or 1 with Shift (the C-arm keys of the earlier client). */
const CARM_STEP_DEG = 5;
const CARM_FINE_DEG = 1;

/** Input types that take no typed text: on them only the keys the control uses itself (arrows
 * move a radio choice or a slider, Space and Enter press) are theirs. */
const CHOICE_INPUTS = ['radio', 'checkbox', 'range', 'button', 'submit', 'reset', 'color', 'file', 'image'];

/** Whether `key` pressed at `target` belongs to it: anything typed into a text field, a select,
 * a textarea or editable text; the control keys of a radio, checkbox or slider. */
function ownsKey(target, key) {
  if (!target || !target.tagName) return false;
  if (target.isContentEditable || target.tagName === 'TEXTAREA' || target.tagName === 'SELECT') return true;
  if (target.tagName !== 'INPUT') return false;
  if (!CHOICE_INPUTS.includes(target.type)) return true;
  return /^(Arrow|Page|Home$|End$)/.test(key) || key === ' ' || key === 'Enter';
}

/** A key as `aria-keyshortcuts` spells it (WAI-ARIA 1.2: modifiers by their `key` names, so
 * "Control+ArrowRight"; a letter in upper case). */
function ariaKey(key) {
  return key.replace(/^Ctrl\+/, 'Control+').replace(/^(.*\+)?([a-z])$/, (_, m, c) => `${m || ''}${c.toUpperCase()}`);
}

/** The fluoroscopy canvas and its overlays, pointer and keys. `needle` is the NeedleControls;
 * `rotate(dOrbital, dAngular)` turns the C-arm; `shot()` takes a shot; `live()` says whether a
 * session is open; `storage` holds the key map (localStorage). */
export class FluoroScreen {
  constructor({ needle, rotate, shot, live, storage }) {
    this.canvas = $('fluoro');
    this.ctx = this.canvas.getContext('2d');
    this.needle = needle;
    this.rotate = rotate;
    this.shoot = shot;
    this.live = live;
    this.storage = storage;
    this.view = defaultView();
    this.pose = { orbital: 0, angular: 0 };
    this.raw = document.createElement('canvas');
    this.rawCtx = this.raw.getContext('2d', { willReadFrequently: true });
    this.lutCanvas = document.createElement('canvas');
    this.hasImage = false;
    this.rawData = null;
    this.info = { technique: null, pps: null, dose: null, acquisitions: null, fieldMm: null };
    this.geometry = { sidMm: SOURCE_TO_DETECTOR_MM, sodMm: SOURCE_TO_ISOCENTRE_MM };
    this.keys = keymap.load(storage);
    this.store = new ImageStore({
      list: $('stored-images'),
      reference: $('reference-image'),
      caption: $('reference-caption'),
      announce: (text) => { $('announcer').textContent = text; },
    });
    this.pointers = new Map();
    this.drag = null;
    needle.setView({
      pixelAt: (canvas, at) => this.pixelAt(at),
      cursorAt: (p) => {
        const c = imageToCanvas(this.view, this.imageSize(), this.canvasSize(), p);
        return [(100 * c[0]) / this.canvas.width, (100 * c[1]) / this.canvas.height];
      },
      tilt: (dx, dy) => {
        const [ix, iy] = screenToImageDirection(this.view, dx, dy);
        return screenToTilt(this.pose, ix, iy);
      },
    });
    this.wirePointer();
    this.wireKeys();
    this.wireDialog();
    this.keysChanged();
    this.overlay();
  }

  imageSize() { return this.needle.imageSize; }
  canvasSize() { return [this.canvas.width, this.canvas.height]; }

  /** A new session: the default view, a black image, no readouts. */
  reset() {
    this.store.reset();
    this.view = defaultView();
    this.pose = { orbital: 0, angular: 0 };
    this.hasImage = false;
    this.rawData = null;
    this.info = { technique: null, pps: null, dose: null, acquisitions: null, fieldMm: null };
    this.draw();
    this.overlay();
  }

  /** The session's hello: the C-arm's distances when its protocol lists them. */
  hello(live) {
    this.geometry = {
      sidMm: live.constant('fluoroscopy', 'source_to_detector_mm', SOURCE_TO_DETECTOR_MM),
      sodMm: live.constant('fluoroscopy', 'source_to_isocentre_mm', SOURCE_TO_ISOCENTRE_MM),
    };
    this.overlay();
  }

  /** A decoded fluoroscopy frame (`bitmap`, closed here) of the C-arm `pose` it was taken at. */
  frame(bitmap, frame, pose) {
    if (this.raw.width !== frame.width || this.raw.height !== frame.height) {
      this.raw.width = frame.width;
      this.raw.height = frame.height;
    }
    this.rawCtx.drawImage(bitmap, 0, 0);
    bitmap.close();
    this.rawData = null;
    this.hasImage = true;
    this.pose = { ...pose };
    this.draw();
    this.overlay();
  }

  /** The outcome of a fluoroscopy acknowledgement: technique, pulse rate, dose, field. */
  ack(o) {
    if (o.technique) this.info.technique = o.technique;
    if (o.pulse_rate_pps != null) this.info.pps = o.pulse_rate_pps;
    if (o.dose) this.info.dose = o.dose;
    if (o.acquisitions != null) this.info.acquisitions = o.acquisitions;
    if (o.field_mm != null) this.info.fieldMm = o.field_mm;
    this.overlay();
  }

  // ------------------------------------------------------------ drawing

  /** The frame through the look-up table of the window, level and invert. */
  displaySource() {
    if (isIdentityLut(this.view)) return this.raw;
    if (!this.rawData) this.rawData = this.rawCtx.getImageData(0, 0, this.raw.width, this.raw.height);
    const data = new ImageData(new Uint8ClampedArray(this.rawData.data), this.raw.width, this.raw.height);
    applyLut(data.data, lut(this.view.window, this.view.level, this.view.invert));
    this.lutCanvas.width = this.raw.width;
    this.lutCanvas.height = this.raw.height;
    this.lutCanvas.getContext('2d').putImageData(data, 0, 0);
    return this.lutCanvas;
  }

  draw() {
    const { ctx, canvas } = this;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = '#000';
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    if (!this.hasImage) return;
    const t = transform(this.view, [this.raw.width, this.raw.height], this.canvasSize());
    ctx.setTransform(t.a, 0, 0, t.d, t.e, t.f);
    ctx.drawImage(this.displaySource(), 0, 0);
    ctx.setTransform(1, 0, 0, 1, 0, 0);
  }

  /** A new view: drawn, overlays and the marker cursor follow. */
  setView(view) {
    this.view = view;
    this.draw();
    this.overlay();
    this.needle.placeCursor();
  }

  // ------------------------------------------------------------ overlays

  overlay() {
    const letters = edgeLetters(this.pose, this.view);
    for (const edge of ['left', 'right', 'top', 'bottom']) $(`orient-${edge}`).textContent = letters[edge];
    $('corner-view').textContent = viewName(this.pose);
    const t = this.info.technique;
    const pps = this.info.pps != null ? this.info.pps : t && t.pulse_rate_pps;
    $('corner-technique').textContent = t
      ? `${t.kvp} kVp ${Number(t.ma).toFixed(1)} mA${pps != null ? ` · ${pps} p/s` : ''}`
      : (pps != null ? `${pps} p/s` : '');
    const d = this.info.dose;
    const parts = [];
    if (this.info.acquisitions != null) parts.push(`${this.info.acquisitions} ${this.info.acquisitions === 1 ? 'shot' : 'shots'}`);
    if (d) parts.push(`${Number(d.fluoro_time_s).toFixed(1)} s`, `${Number(d.air_kerma_mgy).toFixed(2)} mGy (est.)`);
    $('corner-dose').textContent = parts.join(' · ');
    const v = this.view;
    $('corner-zoom').textContent = `Zoom ${v.zoom.toFixed(2)}× · W ${Math.round(v.window)} L ${Math.round(v.level)}${v.invert ? ' · inverted' : ''}`;
    const bar = $('scale-bar');
    if (this.info.fieldMm == null) { bar.hidden = true; return; }
    const s = scaleBar({ fieldMm: this.info.fieldMm, imagePx: this.imageSize()[0], canvasPx: this.canvas.width, zoom: v.zoom, ...this.geometry });
    bar.hidden = false;
    bar.style.width = `${(100 * s.fraction).toFixed(3)}%`;
    bar.dataset.mm = String(s.mm);
    bar.dataset.fraction = String(s.fraction);
    $('scale-label').textContent = `${s.mm} mm`;
  }

  // ------------------------------------------------------------ pointer

  /** Image pixel under client point `at`. */
  pixelAt(at) {
    const r = this.canvas.getBoundingClientRect();
    const c = [((at.x - r.left) * this.canvas.width) / r.width, ((at.y - r.top) * this.canvas.height) / r.height];
    return canvasToImage(this.view, this.imageSize(), this.canvasSize(), c);
  }

  /** Canvas pixels per CSS pixel (the canvas is shown at its CSS size). */
  cssScale() {
    const r = this.canvas.getBoundingClientRect();
    return this.canvas.width / (r.width || this.canvas.width);
  }

  /** A viewer drag ('wl', 'zoom', 'pan') from client point `at`: `move`, `end`, `cancel`. */
  viewDrag(kind, at) {
    const start = this.view;
    const k = this.cssScale();
    const apply = (p) => {
      const dx = p.x - at.x;
      const dy = p.y - at.y;
      if (kind === 'wl') return windowLevelDrag(start, dx, dy);
      if (kind === 'zoom') return zoomDrag(start, dy);
      return panBy(start, dx * k, dy * k);
    };
    return { move: (p) => this.setView(apply(p)), end: () => {}, cancel: () => this.setView(start) };
  }

  dragPoint() {
    const ps = [...this.pointers.values()];
    return { x: ps.reduce((s, p) => s + p.x, 0) / ps.length, y: ps.reduce((s, p) => s + p.y, 0) / ps.length };
  }

  wirePointer() {
    const c = this.canvas;
    c.addEventListener('contextmenu', (e) => e.preventDefault());
    c.addEventListener('pointerdown', (e) => {
      this.pointers.set(e.pointerId, { x: e.clientX, y: e.clientY });
      c.setPointerCapture(e.pointerId);
      // The middle button would start the browser's auto-scroll.
      if (e.button === 1) e.preventDefault();
      if (this.drag) this.drag.end();
      const at = this.dragPoint();
      let kind;
      if (this.pointers.size > 1 || (e.shiftKey && e.button === 0)) kind = 'hub';
      else if (e.button === 2) kind = 'zoom';
      else if (e.button === 1) kind = 'pan';
      else kind = this.needle.mode();
      if (kind === 'view') kind = 'wl';
      this.drag = ['wl', 'zoom', 'pan'].includes(kind) ? this.viewDrag(kind, at) : this.needle.drag(kind, at, c);
    });
    c.addEventListener('pointermove', (e) => {
      if (!this.pointers.has(e.pointerId)) return;
      this.pointers.set(e.pointerId, { x: e.clientX, y: e.clientY });
      if (this.drag) this.drag.move(this.dragPoint());
    });
    // A finger lifted from a two-finger tilt ends the drag (the rest would jump the midpoint).
    const end = (e) => {
      this.pointers.delete(e.pointerId);
      if (this.drag) { this.drag.end(); this.drag = null; }
    };
    c.addEventListener('pointerup', end);
    c.addEventListener('pointercancel', end);
    c.addEventListener('wheel', (e) => {
      if (!this.live()) return;
      e.preventDefault();
      this.needle.wheel(e);
    }, { passive: false });
  }

  /** Escape: a viewer drag in flight goes back to where it started; a marker or hub drag stops
   * (what it sent stays sent). */
  cancelDrag() {
    if (!this.drag) return false;
    if (this.drag.cancel) this.drag.cancel(); else this.drag.end();
    this.drag = null;
    return true;
  }

  // ------------------------------------------------------------ keys

  /** Whether the fluoroscopy screen is the one on show. */
  active() {
    return !$('session-view').hidden && !$('fluoro-viewer').hidden;
  }

  wireKeys() {
    document.addEventListener('keydown', (e) => {
      if (e.defaultPrevented || e.isComposing || !this.active()) return;
      const t = e.target;
      if (ownsKey(t, e.key) || (t.closest && t.closest('#us-station, dialog'))) return;
      const key = keymap.eventKey(e);
      const id = keymap.actionFor(this.keys, key);
      if (!id) return;
      // Space and Enter on a button press the button.
      if ((key === 'Space' || key === 'Enter') && t.closest && t.closest('button, a[href], summary')) return;
      e.preventDefault();
      this.run(id, e.shiftKey);
    });
  }

  /** Runs action `id` of the key map; `fine` is Shift. */
  run(id, fine) {
    const v = this.view;
    const step = fine ? CARM_FINE_DEG : CARM_STEP_DEG;
    const arrows = { nudgeUp: [0, 1], nudgeDown: [0, -1], nudgeLeft: [-1, 0], nudgeRight: [1, 0] };
    if (arrows[id]) {
      const a = arrows[id];
      if (this.needle.nudge(a, fine)) return;
      const px = fine ? PAN_FINE_PX : PAN_KEY_PX;
      this.setView(panBy(v, a[0] * px, -a[1] * px));
      return;
    }
    if (this.needle.action(id, fine)) return;
    const act = {
      help: () => this.openDialog(),
      reset: () => this.setView(defaultView()),
      invert: () => this.setView({ ...v, invert: !v.invert }),
      flipH: () => this.setView({ ...v, flipH: !v.flipH }),
      flipV: () => this.setView({ ...v, flipV: !v.flipV }),
      zoomIn: () => this.setView(zoomBy(v, ZOOM_STEP)),
      zoomOut: () => this.setView(zoomBy(v, 1 / ZOOM_STEP)),
      cancel: () => this.cancelDrag(),
      store: () => {
        if (this.hasImage) this.store.store(this.raw, viewName(this.pose));
        else $('announcer').textContent = 'No image to store yet: take a shot first.';
      },
      modeView: () => this.needle.setMode('view'),
      modeMarker: () => this.needle.setMode('marker'),
      modeHub: () => this.needle.setMode('hub'),
      shot: () => this.shoot(),
      carmLao: () => this.rotate(step, 0),
      carmRao: () => this.rotate(-step, 0),
      carmCranial: () => this.rotate(0, step),
      carmCaudal: () => this.rotate(0, -step),
    }[id];
    if (act) act();
  }

  /** The key help under the image, the buttons' `aria-keyshortcuts` and the dialog's rows,
   * all from the key map, so none of them can disagree with it. */
  keysChanged() {
    const help = $('fluoro-keys');
    const groups = new Map();
    for (const a of keymap.ACTIONS) {
      if (!groups.has(a.group)) groups.set(a.group, []);
      groups.get(a.group).push(a);
    }
    const parts = [document.createTextNode('Keys (anywhere on the page except in form fields; ')];
    const q = document.createElement('kbd');
    q.textContent = keymap.keyLabel(this.keys.help);
    parts.push(q, document.createTextNode(' lists and changes them). '));
    for (const [group, actions] of groups) {
      const span = document.createElement('span');
      span.className = 'key-group';
      span.append(`${group}: `);
      actions.forEach((a, i) => {
        const k = document.createElement('kbd');
        k.textContent = keymap.keyLabel(this.keys[a.id]);
        k.dataset.action = a.id;
        span.append(k, ` ${a.label}${i + 1 < actions.length ? '; ' : '. '}`);
      });
      parts.push(span);
    }
    help.replaceChildren(...parts);
    this.canvas.setAttribute('aria-label', 'Fluoroscopy image. Left drag adjusts window and level, or moves the skin marker or tilts the needle hub in those modes; '
      + 'right drag zooms, middle drag pans; the wheel advances and withdraws the needle. '
      + `The keys are listed below; press ${keymap.keyLabel(this.keys.help)} for the key map.`);
    const shortcuts = {
      shot: this.keys.shot, puncture: this.keys.puncture, 'feed-1': this.keys.feed, 'withdraw-1': this.keys.withdraw,
      'roll-90': this.keys.roll, aspirate: this.keys.aspirate, 'carm-rao': this.keys.carmRao, 'carm-lao': this.keys.carmLao,
      'carm-cranial': this.keys.carmCranial, 'carm-caudal': this.keys.carmCaudal,
    };
    for (const [id, key] of Object.entries(shortcuts)) $(id).setAttribute('aria-keyshortcuts', ariaKey(key));
    for (const [mode, action] of [['view', 'modeView'], ['marker', 'modeMarker'], ['hub', 'modeHub']]) {
      const input = document.querySelector(`input[name="drag-mode"][value="${mode}"]`);
      if (input) input.setAttribute('aria-keyshortcuts', ariaKey(this.keys[action]));
    }
    this.renderDialog();
  }

  // ------------------------------------------------------------ the key map dialog

  openDialog() {
    const d = $('keymap-dialog');
    if (d.open) return;
    $('keymap-message').textContent = '';
    this.capturing = null;
    this.renderDialog();
    d.showModal();
  }

  renderDialog() {
    const rows = keymap.ACTIONS.map((a) => {
      const tr = document.createElement('tr');
      const th = document.createElement('th');
      th.scope = 'row';
      th.textContent = a.label;
      const td = document.createElement('td');
      const kbd = document.createElement('kbd');
      kbd.textContent = keymap.keyLabel(this.keys[a.id]);
      td.append(kbd);
      const tdb = document.createElement('td');
      const b = document.createElement('button');
      b.type = 'button';
      b.dataset.action = a.id;
      b.textContent = this.capturing === a.id ? 'Press a key…' : 'Change';
      b.setAttribute('aria-label', `Change the key of: ${a.label}`);
      b.addEventListener('click', () => this.capture(a.id));
      tdb.append(b);
      tr.append(th, td, tdb);
      return tr;
    });
    $('keymap-rows').replaceChildren(...rows);
  }

  /** The next key pressed in the dialog goes to `action` (Escape cancels). */
  capture(action) {
    this.capturing = action;
    const label = keymap.ACTIONS.find((a) => a.id === action).label;
    $('keymap-message').textContent = `Press the new key for "${label}" (Escape cancels).`;
    this.renderDialog();
    const b = $('keymap-rows').querySelector(`button[data-action="${action}"]`);
    if (b) b.focus();
  }

  wireDialog() {
    const d = $('keymap-dialog');
    d.addEventListener('keydown', (e) => {
      // A key press after the one that cancelled a capture closes the dialog as usual.
      this.swallowCancel = false;
      if (!this.capturing) return;
      const key = keymap.eventKey(e);
      if (!key) return;
      e.preventDefault();
      e.stopPropagation();
      const action = this.capturing;
      this.capturing = null;
      if (key === 'Escape') {
        this.swallowCancel = true;
        $('keymap-message').textContent = 'Not changed.';
      } else {
        const r = keymap.remap(this.keys, action, key);
        const saved = r.keys ? keymap.save(this.storage, r.keys) : r;
        if (saved.error) {
          $('keymap-message').textContent = `Not changed: ${saved.error}.`;
        } else {
          this.keys = saved.keys;
          $('keymap-message').textContent = `${keymap.ACTIONS.find((a) => a.id === action).label}: ${keymap.keyLabel(key)}.`;
          this.keysChanged();
        }
      }
      this.renderDialog();
      const b = $('keymap-rows').querySelector(`button[data-action="${action}"]`);
      if (b) b.focus();
    });
    // Escape while a key is awaited cancels the capture, not the dialog (should the browser
    // still make a close request of that key press).
    d.addEventListener('cancel', (e) => {
      if (this.capturing || this.swallowCancel) e.preventDefault();
      this.swallowCancel = false;
    });
    $('keymap-defaults').addEventListener('click', () => {
      this.keys = keymap.defaultKeys();
      this.storage.removeItem(keymap.STORAGE_KEY);
      this.capturing = null;
      $('keymap-message').textContent = 'Default keys restored.';
      this.keysChanged();
    });
    $('keymap-close').addEventListener('click', () => d.close());
    d.addEventListener('close', () => { this.capturing = null; });
  }
}
