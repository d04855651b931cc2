// The ultrasound station: the B-mode view with its depth scale, focus marker and orientation
// marker; the placement view (the patient's back with the probe), where the probe is dragged;
// probe keys; the scanner's controls; and placing the needle in the scan plane.
//
// Everything drawn comes from the worker: frames (view codes 1 and 2) and the outcome of every
// ultrasound command's acknowledgement (probe, pose, settings, image geometry, needle in
// slice). Needle acknowledgements carry what the scan plane shows of the needle under
// `outcome.ultrasound`; on connecting the client asks for the state once with
// `probe_settings {}` (a command that changes nothing).

const $ = (id) => document.getElementById(id);

/** Margins around the B-mode image on its canvas, px: the orientation dot on the left, the
 * depth scale and focus marker on the right (simulator choice). The image itself is drawn
 * 1:1, so its pixels are the frame's. */
export const BMODE_MARGIN = { left: 16, right: 46, top: 14, bottom: 10 };
/** Probe keys: slide per arrow press, mm (5 with Ctrl); rock / tilt per Shift+arrow, degrees;
 * rotation per Q / E press, degrees. Simulator choice: hand-sized steps (the worker accepts
 * up to 100 mm and 60 degrees per command). */
export const SLIDE_STEP_MM = 1;
export const SLIDE_STEP_LARGE_MM = 5;
export const TILT_STEP_DEG = 2;
export const ROTATE_STEP_DEG = 5;
/** At most one drag command per this many ms while dragging (as the C-arm drag). */
const DRAG_INTERVAL_MS = 50;
/** In-plane needle: entry this far beyond the end of the probe face along the skin, mm, and this
 * far outside the skin (simulator choice: a hand's breadth from the probe is too far for the
 * 89 mm needle, 5 mm keeps the hub clear of the face). */
const ENTRY_BEYOND_FACE_MM = 5;
const ENTRY_OUTSIDE_SKIN_MM = 2;
/** Half chord of the probe faces, mm (sim_core::ultrasound::ProbeKind::spec: linear 38 mm
 * footprint; curvilinear radius 60 mm over 60 degrees, chord half 60 sin 30 deg). */
const FACE_HALF_CHORD_MM = { linear: 19, curvilinear: 30 };

const add = (a, b) => a.map((v, i) => v + b[i]);
const scale = (a, k) => a.map((v) => v * k);
const dot = (a, b) => a.reduce((s, v, i) => s + v * b[i], 0);
const norm = (a) => { const l = Math.hypot(...a) || 1; return a.map((v) => v / l); };
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];

function el(tag, props = {}) {
  return Object.assign(document.createElement(tag), props);
}

/** Words for what the scan plane shows of the needle. */
export function needleWords(o) {
  if (!o) return '–';
  // Assessment mode: the session sends no hints; the image is all there is.
  if (!('tip_in_slice' in o) && !('needle_in_slice' in o)) return 'no hints (assessment): judge the needle from the image';
  if (o.tip_in_slice) return 'needle in plane: tip in the slice';
  if (o.needle_in_slice) return 'shaft crosses the slice (the tip is not in it)';
  return 'needle not in the slice';
}

/** The ultrasound part of a live session. `send(command)` sends a command and returns its
 * sequence number (null when no session is open); `log(text)` shows a line to the learner. */
export class UltrasoundStation {
  constructor({ send, log }) {
    this.send = send;
    this.log = log;
    this.active = false;
    this.margin = BMODE_MARGIN;
    this.bitmap = null;
    this.clear();
    this.dragging = false;
    this.dragTimer = null;
    this.lastDragSent = 0;
    this.dragPixel = null;
    this.pendingMove = null;
    this.moveTimer = null;
    this.lastMoveSent = 0;
    this.wire();
  }

  /** Forgets the state of a previous session. */
  clear() {
    /** Newest ultrasound outcome, and the image geometry after each acknowledged command. */
    this.outcome = null;
    this.geometry = [];
    /** Per view: the newest drawn frame's sequence numbers, and how many were drawn. */
    this.drawn = {};
    this.asked = false;
    /** Sequence number of the newest state query (`probe_settings {}`, which changes nothing and
     * so brings no new frame). */
    this.lastQuerySeq = null;
    if (this.bitmap) this.bitmap.close();
    this.bitmap = null;
    this.bitmapFrame = null;
  }

  /** A new session at `station` (its tray gives the probes). */
  reset(station) {
    this.station = station;
    this.clear();
    const probes = (station.instruments || []).filter((i) => i.kind === 'ultrasound-probe');
    $('us-probe').replaceChildren(...probes.map((i) => el('option', { value: i.id, textContent: i.id })));
    $('us-probe').disabled = probes.length === 0;
    this.setActive((station.modalities || []).includes('ultrasound'));
    for (const id of ['bmode', 'placement']) {
      const c = $(id);
      const ctx = c.getContext('2d');
      ctx.fillStyle = '#000';
      ctx.fillRect(0, 0, c.width, c.height);
    }
    this.showOutcome();
  }

  /** Shows or hides the station (the session's `hello` lists its views). */
  setActive(on) {
    this.active = on;
    $('us-station').hidden = !on;
  }

  /** After every hello: ask for the probe's state once per session. */
  hello(views) {
    this.setActive(views.includes('ultrasound'));
    if (this.active && !this.outcome && !this.asked) {
      this.asked = true;
      this.query();
    }
  }

  /** Draws a frame of the ultrasound or placement view; false for other views. */
  frame(f, bitmap) {
    if (f.view !== 'ultrasound' && f.view !== 'placement') return false;
    const d = this.drawn[f.view] || (this.drawn[f.view] = { frames: 0, frameSeq: -1, inputSeq: 0 });
    // Decoding is asynchronous: a frame that finished after a newer one is dropped.
    if (f.frameSeq < d.frameSeq) { bitmap.close(); return true; }
    if (f.view === 'placement') {
      const c = $('placement');
      if (c.width !== f.width || c.height !== f.height) { c.width = f.width; c.height = f.height; }
      c.getContext('2d').drawImage(bitmap, 0, 0);
      bitmap.close();
    } else {
      if (this.bitmap) this.bitmap.close();
      this.bitmap = bitmap;
      this.bitmapFrame = f;
      this.drawBmode();
      // A draft (a cheap preview while the probe moves) says so until the full frame comes.
      $('us-draft').hidden = !f.draft;
    }
    Object.assign(d, { frames: d.frames + 1, frameSeq: f.frameSeq, inputSeq: f.inputSeq, draft: !!f.draft });
    return true;
  }

  /** The image geometry that a frame reflecting input `seq` was made with. */
  geometryFor(seq) {
    let g = null;
    for (const e of this.geometry) if (e.seq <= seq) g = e.image;
    return g || (this.outcome && this.outcome.image);
  }

  /** The B-mode image with its depth scale (cm), focus marker and orientation dot. */
  drawBmode() {
    const f = this.bitmapFrame;
    if (!f || !this.bitmap) return;
    const m = BMODE_MARGIN;
    const c = $('bmode');
    const w = f.width + m.left + m.right;
    const h = f.height + m.top + m.bottom;
    if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
    const ctx = c.getContext('2d');
    ctx.fillStyle = '#000';
    ctx.fillRect(0, 0, w, h);
    ctx.drawImage(this.bitmap, m.left, m.top);
    // Orientation marker: the image's left edge is the probe's marker side.
    ctx.fillStyle = '#4cf';
    ctx.beginPath();
    ctx.arc(m.left / 2, m.top + 6, 4, 0, 2 * Math.PI);
    ctx.fill();
    const g = this.geometryFor(f.inputSeq);
    if (!g) return;
    // Rows: depth below the face centre = origin_mm[1] + row * pixel_mm (scaled if the frame
    // and the geometry disagree in height, which they do not for matching sequences).
    const ky = f.height / g.height;
    const yOf = (depthMm) => m.top + ((depthMm - g.origin_mm[1]) / g.pixel_mm) * ky;
    const x0 = m.left + f.width + 3;
    ctx.strokeStyle = '#ccc';
    ctx.fillStyle = '#ddd';
    ctx.lineWidth = 1;
    ctx.font = '11px system-ui, sans-serif';
    ctx.textBaseline = 'middle';
    ctx.beginPath();
    ctx.moveTo(x0 + 0.5, yOf(0));
    ctx.lineTo(x0 + 0.5, yOf(g.depth_mm));
    for (let cm = 0; cm * 10 <= g.depth_mm + 1e-6; cm++) {
      const y = Math.round(yOf(cm * 10)) + 0.5;
      ctx.moveTo(x0, y);
      ctx.lineTo(x0 + (cm % 5 === 0 ? 9 : 6), y);
    }
    // Half-centimetre minor ticks.
    for (let mm = 5; mm <= g.depth_mm + 1e-6; mm += 10) {
      const y = Math.round(yOf(mm)) + 0.5;
      ctx.moveTo(x0, y);
      ctx.lineTo(x0 + 3, y);
    }
    ctx.stroke();
    for (let cm = 0; cm * 10 <= g.depth_mm + 1e-6; cm++) {
      ctx.fillText(cm === 0 ? '0 cm' : String(cm), x0 + 12, Math.min(h - 6, Math.max(6, yOf(cm * 10))));
    }
    // Focus: a triangle pointing at the image at the focal depth.
    const yf = yOf(g.focus_mm);
    ctx.fillStyle = '#fc3';
    ctx.beginPath();
    ctx.moveTo(x0 - 2, yf);
    ctx.lineTo(x0 + 8, yf - 5);
    ctx.lineTo(x0 + 8, yf + 5);
    ctx.closePath();
    ctx.fill();
  }

  /** An acknowledgement: picks out ultrasound outcomes. */
  ack(a) {
    const o = a.outcome;
    if (o && typeof o === 'object' && o.ultrasound && this.outcome) {
      // A needle command: what the scan plane shows of the needle now.
      this.outcome = { ...this.outcome, ...o.ultrasound };
      this.showOutcome();
      return;
    }
    if (!o || typeof o !== 'object' || !o.settings || !o.probe) return;
    this.outcome = o;
    if (o.image) {
      this.geometry.push({ seq: a.seq, image: o.image });
      if (this.geometry.length > 64) this.geometry.shift();
    }
    this.showOutcome();
    // The frame on screen may reflect this command already (frames can overtake acks).
    if (this.bitmapFrame && this.bitmapFrame.inputSeq >= a.seq) this.drawBmode();
  }

  /** Puts the newest state into the controls and readouts. */
  showOutcome() {
    const o = this.outcome;
    const s = o && o.settings;
    const set = (id, v, digits, unit) => {
      if (v == null) return;
      if (document.activeElement !== $(id) || !this.editing) $(id).value = String(v);
      $(`${id}-out`).textContent = `${Number(v).toFixed(digits)} ${unit}`;
    };
    if (o) {
      $('us-probe').value = o.instrument || $('us-probe').value;
      $('us-depth').min = String(o.depth_range_mm[0]);
      $('us-depth').max = String(o.depth_range_mm[1]);
      $('us-frequency').min = String(o.band_mhz[0]);
      $('us-frequency').max = String(o.band_mhz[1]);
      $('us-focus').max = String(s.depth_mm);
      set('us-depth', s.depth_mm, 0, 'mm');
      $('us-depth-out').textContent = `${+(s.depth_mm / 10).toFixed(1)} cm`;
      set('us-gain', s.gain_db, 0, 'dB');
      set('us-focus', s.focus_mm, 0, 'mm');
      set('us-frequency', s.frequency_mhz, 1, 'MHz');
      set('us-dr', s.dynamic_range_db, 0, 'dB');
      s.tgc_db.forEach((v, i) => set(`us-tgc-${i}`, v, 0, 'dB'));
      $('us-freeze').setAttribute('aria-pressed', String(!!o.frozen));
      $('us-freeze').textContent = o.frozen ? 'Unfreeze' : 'Freeze';
      $('us-frozen').textContent = o.frozen ? 'FROZEN' : '';
      const p = o.position_mm.map((v) => v.toFixed(1)).join(', ');
      $('us-pose').textContent = `face at (${p}) mm, ${o.probe}`;
    }
    $('us-feedback').textContent = needleWords(o);
    $('us-feedback').dataset.tip = String(!!(o && o.tip_in_slice));
  }

  /** Asks for the probe's state with a command that changes nothing. */
  query() {
    this.lastQuerySeq = this.send({ type: 'probe_settings' });
  }

  settings(fields) {
    this.send({ type: 'probe_settings', ...fields });
  }

  /** A probe step from the keys. Steps within one interval (a held key repeats about 30 times
   * a second) are summed into one `probe_move`, at most one per DRAG_INTERVAL_MS as for drags;
   * the first goes at once. */
  move(slide, tilt, rotate) {
    const m = this.pendingMove || (this.pendingMove = { slide: [0, 0], tilt: [0, 0], rotate: 0 });
    if (slide) m.slide = m.slide.map((v, i) => v + slide[i]);
    if (tilt) m.tilt = m.tilt.map((v, i) => v + tilt[i]);
    if (rotate) m.rotate += rotate;
    if (this.moveTimer) return;
    const since = performance.now() - this.lastMoveSent;
    if (since >= DRAG_INTERVAL_MS) this.flushMove();
    else this.moveTimer = setTimeout(() => this.flushMove(), DRAG_INTERVAL_MS - since);
  }

  flushMove() {
    this.moveTimer = null;
    const m = this.pendingMove;
    this.pendingMove = null;
    if (!m) return;
    this.lastMoveSent = performance.now();
    const c = { type: 'probe_move' };
    if (m.slide.some((v) => v !== 0)) c.slide_mm = m.slide;
    if (m.tilt.some((v) => v !== 0)) c.tilt_deg = m.tilt;
    if (m.rotate !== 0) c.rotate_deg = m.rotate;
    if (Object.keys(c).length > 1) this.send(c);
  }

  /** Probe keys on either ultrasound canvas (listed on screen in #us-keys). */
  key(e) {
    const k = e.key.length === 1 ? e.key.toLowerCase() : e.key;
    const mm = e.ctrlKey || e.metaKey ? SLIDE_STEP_LARGE_MM : SLIDE_STEP_MM;
    const t = TILT_STEP_DEG;
    const arrows = e.shiftKey
      ? { ArrowLeft: () => this.move(null, [t, 0]), ArrowRight: () => this.move(null, [-t, 0]),
        ArrowUp: () => this.move(null, [0, t]), ArrowDown: () => this.move(null, [0, -t]) }
      : { ArrowLeft: () => this.move([mm, 0]), ArrowRight: () => this.move([-mm, 0]),
        ArrowUp: () => this.move([0, mm]), ArrowDown: () => this.move([0, -mm]) };
    const handled = {
      ...arrows,
      q: () => this.move(null, null, -ROTATE_STEP_DEG),
      e: () => this.move(null, null, ROTATE_STEP_DEG),
      ' ': () => this.toggleFreeze(),
      f: () => this.send({ type: 'needle_feed', mm: 1 }),
      w: () => this.send({ type: 'needle_withdraw', mm: 1 }),
    }[k];
    if (handled && !e.altKey) { e.preventDefault(); handled(); }
  }

  toggleFreeze() {
    const on = $('us-freeze').getAttribute('aria-pressed') !== 'true';
    this.send({ type: 'probe_freeze', on });
  }

  /** Drag on the placement view: the probe goes to the skin under the pointer. */
  sendDrag(now = false) {
    if (!this.dragPixel) return;
    const go = () => {
      this.lastDragSent = performance.now();
      this.send({ type: 'probe_drag', pixel: this.dragPixel });
    };
    clearTimeout(this.dragTimer);
    const since = performance.now() - this.lastDragSent;
    if (now || since >= DRAG_INTERVAL_MS) go(); else this.dragTimer = setTimeout(go, DRAG_INTERVAL_MS - since);
  }

  pixelOf(e) {
    const c = $('placement');
    const r = c.getBoundingClientRect();
    return [(e.clientX - r.left) * (c.width / r.width), (e.clientY - r.top) * (c.height / r.height)];
  }

  /** Places the chosen needle at the skin beyond one end of the probe, aimed in the scan plane
   * at a point on the central beam line `aim depth` below the face. */
  placeInPlane(instrument) {
    const o = this.outcome;
    if (!o) { this.log('No probe state yet.'); return; }
    const marker = norm(o.marker_dir);
    const beam = norm(o.beam_dir);
    const side = $('us-needle-side').value === 'marker' ? 1 : -1;
    const half = FACE_HALF_CHORD_MM[o.probe] ?? 30;
    const entry = add(add(o.position_mm, scale(marker, side * (half + ENTRY_BEYOND_FACE_MM))), scale(beam, -ENTRY_OUTSIDE_SKIN_MM));
    const aim = add(o.position_mm, scale(beam, Number($('us-needle-aim').value)));
    const direction = norm(add(aim, scale(entry, -1)));
    // The bevel faces across the scan plane (the elevation axis), perpendicular to the shaft.
    const bevel = norm(cross(marker, beam));
    this.send({ type: 'needle_place', instrument, entry_mm: entry, direction, bevel_reference: bevel });
  }

  wire() {
    const onKey = (e) => this.key(e);
    $('bmode').addEventListener('keydown', onKey);
    $('placement').addEventListener('keydown', onKey);
    const pl = $('placement');
    pl.addEventListener('pointerdown', (e) => {
      this.dragging = true;
      pl.setPointerCapture(e.pointerId);
      this.dragPixel = this.pixelOf(e);
      this.sendDrag();
    });
    pl.addEventListener('pointermove', (e) => {
      if (!this.dragging) return;
      this.dragPixel = this.pixelOf(e);
      this.sendDrag();
    });
    const end = () => { if (this.dragging) { this.dragging = false; this.sendDrag(true); this.dragPixel = null; } };
    pl.addEventListener('pointerup', end);
    pl.addEventListener('pointercancel', end);
    $('us-probe').addEventListener('change', (e) => this.send({ type: 'probe_select', instrument: e.target.value }));
    // Sliders: the readout follows while moving; the command goes on release (or per key step).
    const slider = (id, unit, digits, toFields) => {
      const input = $(id);
      input.addEventListener('input', () => {
        this.editing = true;
        $(`${id}-out`).textContent = `${Number(input.value).toFixed(digits)} ${unit}`;
        if (id === 'us-depth') $(`${id}-out`).textContent = `${+(Number(input.value) / 10).toFixed(1)} cm`;
      });
      input.addEventListener('change', () => { this.editing = false; this.settings(toFields(Number(input.value))); });
    };
    slider('us-depth', 'mm', 0, (v) => ({ depth_mm: v }));
    slider('us-gain', 'dB', 0, (v) => ({ gain_db: v }));
    slider('us-focus', 'mm', 0, (v) => ({ focus_mm: v }));
    slider('us-frequency', 'MHz', 1, (v) => ({ frequency_mhz: v }));
    slider('us-dr', 'dB', 0, (v) => ({ dynamic_range_db: v }));
    for (let i = 0; i < 6; i++) {
      slider(`us-tgc-${i}`, 'dB', 0, () => ({ tgc_db: Array.from({ length: 6 }, (_, j) => Number($(`us-tgc-${j}`).value)) }));
    }
    $('us-freeze').addEventListener('click', () => this.toggleFreeze());
    $('us-depth-less').addEventListener('click', () => this.stepDepth(-10));
    $('us-depth-more').addEventListener('click', () => this.stepDepth(10));
  }

  /** Depth buttons: one centimetre shallower or deeper, within the probe's range. */
  stepDepth(mm) {
    if (!this.outcome) return;
    const [lo, hi] = this.outcome.depth_range_mm;
    const d = Math.min(hi, Math.max(lo, this.outcome.settings.depth_mm + mm));
    if (d !== this.outcome.settings.depth_mm) this.settings({ depth_mm: d });
  }
}
