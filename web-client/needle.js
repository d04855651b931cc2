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

  /** What drag and arrows on the image act on: 'carm', 'marker' or 'hub'. */
  mode() {
    const checked = document.querySelector('input[name="drag-mode"]:checked');
    return checked ? checked.value : 'carm';
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
    const cur = $('marker-cursor');
    cur.style.left = `${(100 * this.markerPixel[0]) / w}%`;
    cur.style.top = `${(100 * this.markerPixel[1]) / h}%`;
    cur.hidden = false;
    this.markerThrottle.call();
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
   * image's). */
  pixelAt(canvas, at) {
    const r = canvas.getBoundingClientRect();
    return [((at.x - r.left) * this.imageSize[0]) / r.width, ((at.y - r.top) * this.imageSize[1]) / r.height];
  }

  /** A drag of `kind` ('marker' or 'hub') starting at screen point `at` on `canvas`: an object
   * with `move(at)` and `end()`. Dragging the hub is dragging where the tip should aim in the
   * image: up aims cranially, right towards the patient's left (in AP the patient's right is on
   * the screen's left). */
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
        const cc = round((start.y - p.y) / TILT_PX_PER_DEG, TILT_QUANTUM_DEG);
        const ml = round((p.x - start.x) / TILT_PX_PER_DEG, TILT_QUANTUM_DEG);
        if (cc === sent.cc && ml === sent.ml) return;
        this.tiltBy(cc - sent.cc, ml - sent.ml);
        Object.assign(sent, { cc, ml });
      },
      end: () => this.tiltThrottle.flush(),
    };
  }

  /** Keys on the fluoroscopy canvas that act on the needle; true when handled. Arrows act here
   * in the marker and hub modes (the C-arm mode leaves them to the caller). */
  key(e) {
    const k = e.key.length === 1 ? e.key.toLowerCase() : e.key;
    const mm = e.shiftKey ? FINE_STEP_MM : STEP_MM;
    const arrow = { ArrowUp: [0, 1], ArrowDown: [0, -1], ArrowLeft: [-1, 0], ArrowRight: [1, 0] }[k];
    const mode = this.mode();
    if (arrow && mode === 'hub') {
      const d = e.shiftKey ? TILT_FINE_DEG : TILT_STEP_DEG;
      this.tiltBy(arrow[1] * d, arrow[0] * d);
      return true;
    }
    if (arrow && mode === 'marker') {
      const d = e.shiftKey ? 1 : MARKER_KEY_PX;
      const p = this.markerPixel || this.imageSize.map((v) => v / 2);
      this.moveMarker([p[0] + arrow[0] * d, p[1] - arrow[1] * d]);
      return true;
    }
    const action = {
      f: () => this.feed(mm),
      w: () => this.withdraw(mm),
      r: () => this.send({ type: 'needle_roll', deg: 90 }),
      p: () => this.puncture(),
      a: () => this.send({ type: 'aspirate' }),
      c: () => this.setMode('carm'),
      m: () => this.setMode('marker'),
      h: () => this.setMode('hub'),
    }[k];
    if (!action || e.ctrlKey || e.metaKey || e.altKey) return false;
    action();
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
