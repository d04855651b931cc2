// Hands-on needle handling on the fluoroscopy image: the radio-opaque skin marker, the puncture,
// hub tilt, advance and withdraw in small steps, the force the hand feels, the loss-of-resistance
// syringe and aspiration (session commands of issue 19).
//
// What is shown is what a physician has: the force on the hub, the feel of the plunger, what the
// syringe draws back, the depth marks on the shaft and how far the hub was tilted. Never where
// the tip is: the worker's texts describe the hand's sensations only, and positions in the acks
// (`marker_mm`, `tip_mm`) are not displayed.

const $ = (id) => document.getElementById(id);

/** Hub tilt per arrow key or tilt button press, degrees (1 with Shift). Simulator choice: a
 * hand's small correction; the worker accepts up to 20 degrees per command. */
export const TILT_STEP_DEG = 2;
export const TILT_FINE_DEG = 1;
/** Hub tilt per screen pixel of a drag: 8 px per degree (simulator choice: a 45 degree limit is
 * 360 px, most of the image). Drags send tilts in 0.5 degree steps. */
const TILT_PX_PER_DEG = 8;
const TILT_QUANTUM_DEG = 0.5;
/** Largest tilt the worker takes in one command, degrees (protocol: |each| <= 20). */
const TILT_MAX_DEG = 20;
/** Feed / withdraw steps, mm: plain 1, with Shift 0.5 (simulator choice). */
export const STEP_MM = 1;
export const FINE_STEP_MM = 0.5;
/** Skin marker keys: image pixels per arrow press (1 with Shift). Simulator choice. */
const MARKER_KEY_PX = 4;
/** At most one drag command per this many ms (as the C-arm drag: 20 Hz). */
const DRAG_INTERVAL_MS = 50;
/** One wheel step per this much scrolling, CSS px (a mouse wheel notch is 100 in Chromium, 120
 * elsewhere; line-mode deltas count 33 px a line). Simulator choice: half a notch, so trackpads,
 * which send many small deltas, step about as often as a wheel. */
const WHEEL_STEP_PX = 50;
/** Force gauge full scale, N, and the trace's length in samples (0.5 mm apart: the last 40 mm of
 * travel). Simulator choice: the force model's bone stop (sim_core::needle::force::BONE_STOP_N,
 * 10 N) fills the gauge; the flavum peaks at about 6 N in the browser test. The scale grows if a
 * larger force is felt. */
const FORCE_FULL_SCALE_N = 10;
const TRACE_SAMPLES = 80;

/** Calls `fn` at most once per DRAG_INTERVAL_MS; `flush()` runs a pending call at once. */
class Throttle {
  constructor(fn) { this.fn = fn; this.timer = null; this.last = 0; }
  call() {
    if (this.timer) return;
    const wait = DRAG_INTERVAL_MS - (performance.now() - this.last);
    if (wait <= 0) this.run(); else this.timer = setTimeout(() => this.run(), wait);
  }
  flush() { if (this.timer) this.run(); }
  run() { clearTimeout(this.timer); this.timer = null; this.last = performance.now(); this.fn(); }
}

const round = (v, q) => Math.round(v / q) * q;

/** The needle panel, the loss-of-resistance syringe and the needle's drags and keys on the
 * fluoroscopy canvas. `send(command)` sends a command (null without a session); `log(text)`
 * shows a line to the learner. */
export class NeedleControls {
  constructor({ send, log }) {
    this.post = send;
    this.log = log;
    /** Commands sent and not yet answered, by sequence number (acks are read by command). */
    this.sent = new Map();
    this.imageSize = [512, 512];
    this.markerThrottle = new Throttle(() => this.sendMarker());
    this.tiltThrottle = new Throttle(() => this.sendTilt());
    this.wheelPx = 0;
    /** How the fluoroscopy viewer maps the screen (`setView`); until then, the image fills the
     * canvas unflipped and the view is AP. */
    this.view = {
      pixelAt: (canvas, at) => {
        const r = canvas.getBoundingClientRect();
        return [((at.x - r.left) * this.imageSize[0]) / r.width, ((at.y - r.top) * this.imageSize[1]) / r.height];
      },
      cursorAt: (p) => [(100 * p[0]) / this.imageSize[0], (100 * p[1]) / this.imageSize[1]],
      tilt: (dx, dy) => ({ cc: dy, ml: dx }),
    };
    this.clear();
    this.wire();
  }

  /** Forgets the state of a previous session. */
  clear() {
    this.sent.clear();
    this.markerPixel = null;
    this.markerSent = null;
    this.markerSeq = null;
    this.tilt = null;
    this.trace = [];
    this.peakN = 0;
    this.scaleN = FORCE_FULL_SCALE_N;
    $('marker-cursor').hidden = true;
    $('marker-state').textContent = 'not placed';
    $('hub-deviation').textContent = '–';
    $('force-text').textContent = '–';
    $('force-meter').value = 0;
    $('aspirate-text').textContent = '';
    $('lor-attach').setAttribute('aria-pressed', 'false');
    $('lor-hold').setAttribute('aria-pressed', 'false');
    $('lor-resistance').value = 0;
    $('lor-text').textContent = '–';
    $('lor-injected').textContent = '–';
    this.drawTrace();
  }

  /** A new session at `station` (the LOR syringe shows when its tray has one). */
  reset(station) {
    this.clear();
    $('lor').hidden = !(station.instruments || []).some((i) => i.kind === 'loss-of-resistance-syringe');
  }

  /** What a left drag and the arrows on the image act on: 'view' (window/level and pan),
   * 'marker' or 'hub'. */
  mode() {
    const checked = document.querySelector('input[name="drag-mode"]:checked');
    return checked ? checked.value : 'view';
  }

  /** The viewer's screen mapping: `pixelAt(canvas, {x, y})` (client point -> image pixel, through
   * the inverse of zoom, pan and flips), `cursorAt(p)` (image pixel -> [left %, top %] of the
   * canvas) and `tilt(dx, dy)` (a screen direction, right and up, in degrees -> the hub tilt
   * `{ cc, ml }` in the pose of the displayed image). */
  setView(view) {
    this.view = view;
  }

  setMode(mode) {
    const input = document.querySelector(`input[name="drag-mode"][value="${mode}"]`);
    if (input) input.checked = true;
  }

  /** A new fluoroscopy frame: its size (skin marker pixels are image pixels); once a frame
   * reflects the newest marker command the cursor goes (the image shows the marker itself). */
  fluoroFrame(frame) {
    this.imageSize = [frame.width, frame.height];
    if (this.markerSeq != null && frame.inputSeq >= this.markerSeq) $('marker-cursor').hidden = true;
  }

  // ------------------------------------------------------------ commands

  /** Sends `command`; returns its sequence number (null without a session). */
  send(command) {
    const seq = this.post(command);
    if (seq != null) this.sent.set(seq, command);
    return seq;
  }

  sendMarker() {
    const p = this.markerPixel;
    if (!p || (this.markerSent && p[0] === this.markerSent[0] && p[1] === this.markerSent[1])) return;
    this.markerSent = p;
    this.markerSeq = this.send({ type: 'skin_marker', pixel: p });
  }

  /** Puts the marker cursor at image pixel `p` and sends it (throttled). */
  moveMarker(p) {
    const [w, h] = this.imageSize;
    this.markerPixel = [Math.min(w - 0.5, Math.max(0.5, p[0])), Math.min(h - 0.5, Math.max(0.5, p[1]))].map((v) => round(v, 0.5));
    this.placeCursor();
    $('marker-cursor').hidden = false;
    this.markerThrottle.call();
  }

  /** Puts the marker cursor over the marker's pixel as the viewer now shows it (called again
   * after a zoom, pan or flip). */
  placeCursor() {
    if (!this.markerPixel) return;
    const [left, top] = this.view.cursorAt(this.markerPixel);
    const cur = $('marker-cursor');
    cur.style.left = `${left}%`;
    cur.style.top = `${top}%`;
  }

  /** Hub tilt in degrees: `cc` > 0 aims more cranially, `ml` > 0 towards the patient's left. */
  tiltBy(cc, ml) {
    const t = this.tilt || (this.tilt = { cc: 0, ml: 0 });
    t.cc += cc;
    t.ml += ml;
    this.tiltThrottle.call();
  }

  sendTilt() {
    const t = this.tilt;
    if (!t) return;
    const cc = Math.max(-TILT_MAX_DEG, Math.min(TILT_MAX_DEG, t.cc));
    const ml = Math.max(-TILT_MAX_DEG, Math.min(TILT_MAX_DEG, t.ml));
    t.cc -= cc;
    t.ml -= ml;
    if (t.cc === 0 && t.ml === 0) this.tilt = null; else this.tiltThrottle.call();
    if (cc !== 0 || ml !== 0) this.send({ type: 'needle_tilt', cc_deg: cc, ml_deg: ml });
  }

  feed(mm) { this.send({ type: 'needle_feed', mm }); }
  withdraw(mm) { this.send({ type: 'needle_withdraw', mm }); }

  puncture() {
    this.markerThrottle.flush();
    this.send({ type: 'needle_puncture', instrument: $('instrument').value });
  }

  // ------------------------------------------------------------ drags, keys and the wheel

  /** Image pixel under a pointer position on `canvas` (its CSS size may differ from the
   * image's; the viewer's zoom, pan and flips are undone). */
  pixelAt(canvas, at) {
    return this.view.pixelAt(canvas, at);
  }

  /** A screen direction (right, up; degrees of tilt) as a hub tilt, sent in TILT_QUANTUM_DEG
   * steps by drags. */
  screenTilt(dx, dy) {
    return this.view.tilt(dx, dy);
  }

  /** A drag of `kind` ('marker' or 'hub') starting at screen point `at` on `canvas`: an object
   * with `move(at)` and `end()`. Dragging the hub is dragging where the tip should aim in the
   * image: the screen direction becomes the patient direction of the displayed view (in AP up
   * aims cranially and right towards the patient's left; in a lateral view right is along the
   * beam's cross axis, front to back, and tilts nothing). */
  drag(kind, at, canvas) {
    if (kind === 'marker') {
      this.moveMarker(this.pixelAt(canvas, at));
      return {
        move: (p) => this.moveMarker(this.pixelAt(canvas, p)),
        end: () => this.markerThrottle.flush(),
      };
    }
    const start = at;
    const sent = { cc: 0, ml: 0 };
    return {
      move: (p) => {
        const t = this.screenTilt((p.x - start.x) / TILT_PX_PER_DEG, (start.y - p.y) / TILT_PX_PER_DEG);
        const cc = round(t.cc, TILT_QUANTUM_DEG);
        const ml = round(t.ml, TILT_QUANTUM_DEG);
        if (cc === sent.cc && ml === sent.ml) return;
        this.tiltBy(cc - sent.cc, ml - sent.ml);
        Object.assign(sent, { cc, ml });
      },
      end: () => this.tiltThrottle.flush(),
    };
  }

  /** An arrow (`[right, up]`, one step) in the marker or hub mode; false in any other mode.
   * The marker moves MARKER_KEY_PX image pixels (1 with `fine`) on the screen, so flips are
   * followed; the hub tilts TILT_STEP_DEG (TILT_FINE_DEG with `fine`) towards the screen
   * direction in the pose of the displayed image. */
  nudge(arrow, fine) {
    const mode = this.mode();
    if (mode === 'hub') {
      const d = fine ? TILT_FINE_DEG : TILT_STEP_DEG;
      const t = this.screenTilt(arrow[0] * d, arrow[1] * d);
      this.tiltBy(t.cc, t.ml);
      return true;
    }
    if (mode === 'marker') {
      const d = fine ? 1 : MARKER_KEY_PX;
      const p = this.markerPixel || this.imageSize.map((v) => v / 2);
      // The pixel under the cursor moved by d screen pixels' worth of image pixels: through the
      // viewer, so a flipped image moves the marker the way the key points.
      const [left, top] = this.view.cursorAt(p);
      const [l2, t2] = this.view.cursorAt([p[0] + 1, p[1] + 1]);
      const sx = Math.sign(l2 - left) || 1;
      const sy = Math.sign(t2 - top) || 1;
      this.moveMarker([p[0] + sx * arrow[0] * d, p[1] - sy * arrow[1] * d]);
      return true;
    }
    return false;
  }

  /** A needle action of the key map ('feed', 'withdraw', 'roll', 'puncture', 'aspirate'); `fine`
   * (Shift) halves the feed and withdraw steps. True when `id` is one. */
  action(id, fine) {
    const mm = fine ? FINE_STEP_MM : STEP_MM;
    const act = {
      feed: () => this.feed(mm),
      withdraw: () => this.withdraw(mm),
      roll: () => this.send({ type: 'needle_roll', deg: 90 }),
      puncture: () => this.puncture(),
      aspirate: () => this.send({ type: 'aspirate' }),
    }[id];
    if (!act) return false;
    act();
    return true;
  }

  /** The wheel: away from you advances, towards you withdraws; 1 mm a step, 0.5 with Shift.
   * At most one step per wheel event (a notch is one step whatever its size in pixels). */
  wheel(e) {
    this.wheelPx += (e.deltaY || e.deltaX) * (e.deltaMode === 1 ? 33 : 1);
    if (Math.abs(this.wheelPx) < WHEEL_STEP_PX) return;
    const mm = e.shiftKey ? FINE_STEP_MM : STEP_MM;
    if (this.wheelPx < 0) this.feed(mm); else this.withdraw(mm);
    this.wheelPx = 0;
  }

  // ------------------------------------------------------------ acknowledgements

  /** An acknowledgement: this panel's commands by their type; the force, the plunger and the
   * hub tilt of any needle command (the ultrasound canvas's keys feed the needle too). */
  ack(a) {
    const c = this.sent.get(a.seq) || {};
    this.sent.delete(a.seq);
    const o = a.outcome;
    if (!o || typeof o !== 'object') return;
    switch (c.type) {
      case 'skin_marker':
        $('marker-state').textContent = 'on the skin (shows on the next image)';
        break;
      case 'needle_puncture':
        $('marker-state').textContent = 'removed (the needle is in)';
        $('marker-cursor').hidden = true;
        this.markerPixel = null;
        this.markerSent = null;
        $('hub-deviation').textContent = '0.0°';
        // A new puncture takes the syringe off the old needle (the worker does the same).
        $('lor-attach').setAttribute('aria-pressed', 'false');
        $('lor-hold').setAttribute('aria-pressed', 'false');
        // The marker is used up: drags and arrows now tilt the hub.
        if (this.mode() === 'marker') this.setMode('hub');
        this.log(`Skin punctured with ${c.instrument}.`);
        break;
      case 'syringe': {
        const on = c.action === 'attach';
        $('lor-attach').setAttribute('aria-pressed', String(on));
        if (!on) $('lor-hold').setAttribute('aria-pressed', 'false');
        break;
      }
      case 'plunger_hold':
        $('lor-hold').setAttribute('aria-pressed', String(c.on));
        break;
      case 'aspirate':
        $('aspirate-text').textContent = o.text || o.aspirate;
        break;
      default:
    }
    if (o.hub_deviation_deg != null) $('hub-deviation').textContent = `${o.hub_deviation_deg.toFixed(1)}°`;
    if (o.force) this.showForce(o.force);
    if (o.bone_contact) this.log('A hard stop: the tip meets bone.');
    if (o.lor) this.showLor(o.lor);
  }

  /** A refused command: forgotten here (the caller shows the reason). */
  error(m) {
    if (m.seq != null) this.sent.delete(m.seq);
  }

  showForce(f) {
    this.peakN = Math.max(this.peakN, f.peak_n || 0);
    this.scaleN = Math.max(this.scaleN, Math.ceil(this.peakN));
    $('force-meter').max = this.scaleN;
    $('force-meter').value = Math.max(0, f.total_n);
    $('force-text').textContent = `${f.total_n.toFixed(1)} N (peak ${(f.peak_n || 0).toFixed(1)} N)`;
    for (const s of f.samples || []) this.trace.push(s[1]);
    if (this.trace.length > TRACE_SAMPLES) this.trace.splice(0, this.trace.length - TRACE_SAMPLES);
    this.drawTrace();
  }

  /** The force trace: the hub force along the last TRACE_SAMPLES samples of travel (a sudden
   * drop is the give the hand feels). */
  drawTrace() {
    const c = $('force-trace');
    const ctx = c.getContext('2d');
    ctx.clearRect(0, 0, c.width, c.height);
    ctx.strokeStyle = '#8888';
    ctx.strokeRect(0.5, 0.5, c.width - 1, c.height - 1);
    if (this.trace.length < 2) return;
    ctx.strokeStyle = '#2a7fff';
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    this.trace.forEach((n, i) => {
      const x = 2 + (i * (c.width - 4)) / (TRACE_SAMPLES - 1);
      const y = c.height - 2 - (Math.max(0, n) * (c.height - 4)) / this.scaleN;
      if (i === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
    });
    ctx.stroke();
  }

  showLor(l) {
    $('lor-resistance').value = l.resistance;
    $('lor-text').textContent = l.text;
    $('lor-injected').textContent = `${l.injected_ml.toFixed(2)} mL injected, ${l.remaining_ml.toFixed(2)} mL left`;
  }

  wire() {
    $('puncture').addEventListener('click', () => this.puncture());
    const tilt = (id, cc, ml) => $(id).addEventListener('click', (e) => {
      const d = e.shiftKey ? TILT_FINE_DEG : TILT_STEP_DEG;
      this.tiltBy(cc * d, ml * d);
    });
    tilt('tilt-cranial', 1, 0);
    tilt('tilt-caudal', -1, 0);
    tilt('tilt-left', 0, 1);
    tilt('tilt-right', 0, -1);
    for (const [id, f] of [['feed-05', () => this.feed(0.5)], ['feed-1', () => this.feed(1)], ['feed-5', () => this.feed(5)],
      ['withdraw-05', () => this.withdraw(0.5)], ['withdraw-1', () => this.withdraw(1)],
      ['roll-90', () => this.send({ type: 'needle_roll', deg: 90 })], ['aspirate', () => this.send({ type: 'aspirate' })]]) {
      $(id).addEventListener('click', f);
    }
    $('lor-attach').addEventListener('click', () => {
      const on = $('lor-attach').getAttribute('aria-pressed') === 'true';
      this.send(on ? { type: 'syringe', action: 'detach' } : { type: 'syringe', action: 'attach', medium: $('lor-medium').value });
    });
    $('lor-press').addEventListener('click', () => this.send({ type: 'plunger', ml: Number($('lor-step').value) }));
    $('lor-hold').addEventListener('click', () => {
      this.send({ type: 'plunger_hold', on: $('lor-hold').getAttribute('aria-pressed') !== 'true' });
    });
  }
}
