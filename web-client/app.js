// The main page: health, login, and the learner's live session with its technical result. The
// stations screen is stations.js, the faculty screen faculty.js, what they share ui.js. Plain
// modules, no build step.

import { api, setCsrf, ApiError } from './api.js';
import { $, show, say, fmt, el, outcomeWords } from './ui.js';
import { learnerHome } from './stations.js';
import { facultyHome } from './faculty.js';
import { LiveSession } from './session.js';
import { UltrasoundStation } from './ultrasound.js';
import { NeedleControls } from './needle.js';
import { FluoroScreen } from './fluoro-view.js';
import { viewName } from './orientation.js';

let me = null;
let live = null;
let station = null;

// ---------------------------------------------------------------- health and login

async function health() {
  try {
    const h = await (await fetch('/healthz')).json();
    $('health').textContent = `${h.status} (database ${h.database.ready ? 'ready' : 'not ready'}, render worker ${h.render_worker.state})`;
  } catch {
    $('health').textContent = 'unreachable';
  }
}

async function start() {
  health();
  try {
    const s = await api('GET', '/api/auth/me');
    await loggedIn(s);
  } catch {
    show('login-view');
  }
}

async function loggedIn(s) {
  me = s;
  setCsrf(s.csrf_token);
  $('who').hidden = false;
  $('who-name').textContent = `${s.user.display_name} (${s.user.role}${s.user.is_demo ? ', demo account' : ''})`;
  say('');
  if (s.user.role === 'learner') await learnerHome(openSession);
  else await facultyHome(s);
}

$('login-form').addEventListener('submit', async (ev) => {
  ev.preventDefault();
  const body = { email: $('login-email').value, password: $('login-password').value };
  const code = $('login-totp').value.trim();
  if (code) body.totp_code = code;
  try {
    const s = await api('POST', '/api/auth/login', body);
    $('login-totp').value = '';
    $('login-totp-label').hidden = true;
    await loggedIn(s);
  } catch (e) {
    if (e instanceof ApiError && e.code === 'totp_required') {
      $('login-totp-label').hidden = false;
      $('login-totp').focus();
      say('Enter the code from your authenticator.');
    } else {
      say(e.message);
    }
  }
});

$('logout').addEventListener('click', async () => {
  if (live) { live.close(); live = null; }
  try { await api('POST', '/api/auth/logout'); } catch { /* already gone */ }
  me = null;
  setCsrf(null);
  $('who').hidden = true;
  show('login-view');
});

// ---------------------------------------------------------------- learner: the live session

const pose = { orbital: 0, angular: 0 };
/** The pose commands sent, in order, until a frame shows them: the pose of a displayed image is
 * that of the newest pose command its frame reflects (the overlays and hub tilts follow it). */
let posesSent = [];
let shownPose = { orbital: 0, angular: 0 };
function poseOfFrame(inputSeq) {
  while (posesSent.length && posesSent[0].seq <= inputSeq) {
    const p = posesSent.shift();
    shownPose = { orbital: p.orbital, angular: p.angular };
  }
  return shownPose;
}
let poseTimer = null;
/** Acquisitions the fluoroscopy acknowledgements reported last (null: unknown, a resumed
 * session), and the C-arm view announced last. */
let lastAcquisitions = null;
let lastViewName = 'AP';
let viewAnnounceTimer = null;
let lastPoseSent = 0;

/** The C-arm controls show `pose`. */
function showPose() {
  $('orbital-out').textContent = `${pose.orbital}°`;
  $('angular-out').textContent = `${pose.angular}°`;
  $('orbital').value = pose.orbital;
  $('angular').value = pose.angular;
}

function sendPose(now = false) {
  showPose();
  if (!live) return;
  // At most one pose command per 50 ms while dragging (simulator choice: 20 Hz is smooth for a
  // C-arm and keeps the log short); the final pose is always sent.
  const go = () => {
    lastPoseSent = performance.now();
    const seq = live.send({ type: 'carm_pose', orbital_deg: pose.orbital, angular_deg: pose.angular });
    posesSent.push({ seq, orbital: pose.orbital, angular: pose.angular });
  };
  clearTimeout(poseTimer);
  poseTimer = null;
  const since = performance.now() - lastPoseSent;
  if (now || since >= 50) go(); else poseTimer = setTimeout(() => { poseTimer = null; go(); }, 50 - since);
}

/** A shot: a C-arm move still held back by the throttle goes first, so the image shows the
 * pose the learner set. */
function takeShot() {
  if (!live) return;
  if (poseTimer) sendPose(true);
  live.send({ type: 'shot' });
  if (!$('fluoro-wait').hidden) $('fluoro-wait').textContent = 'Taking the first image…';
}

function clamp(v, lo, hi) { return Math.max(lo, Math.min(hi, v)); }

function rotate(dOrbital, dAngular) {
  pose.orbital = clamp(Math.round(pose.orbital + dOrbital), -90, 90);
  pose.angular = clamp(Math.round(pose.angular + dAngular), -40, 40);
  sendPose();
}

function logLine(text) {
  $('session-log').textContent = text;
}

const us = new UltrasoundStation({ send: (command) => (live ? live.send(command) : null), log: logLine });
const needle = new NeedleControls({ send: (command) => (live ? live.send(command) : null), log: logLine });
const fluoroScreen = new FluoroScreen({
  needle,
  rotate,
  shot: takeShot,
  live: () => !!live,
  storage: window.localStorage,
});

/** Views this page has panels of its own for; any other view a session's modalities offer
 * gets a generic panel (`otherViews`). */
const OWN_VIEWS = ['fluoroscopy', 'ultrasound', 'placement'];
const otherViews = new Map(); // view name -> canvas

/** Shows the panels of the views a session renders: the built-in ones, and one generic panel
 * (title and image) per view of any other modality the hello lists. */
function showViews(views, protocol) {
  const fluoro = views.includes('fluoroscopy');
  $('fluoro-viewer').hidden = !fluoro;
  $('carm-controls').hidden = !fluoro;
  us.hello(views);
  const host = $('other-views');
  host.replaceChildren();
  otherViews.clear();
  for (const name of views.filter((v) => !OWN_VIEWS.includes(v))) {
    const info = ((protocol && protocol.views) || []).find((v) => v.name === name) || {};
    const canvas = el('canvas', { width: 512, height: 512, className: 'other-view' });
    canvas.setAttribute('role', 'img');
    canvas.setAttribute('aria-label', `${name} view (${info.modality || 'modality'})`);
    canvas.dataset.view = name;
    host.append(el('figure', { className: 'viewer' }, canvas, el('figcaption', { textContent: `${name} (${info.modality || ''})` })));
    otherViews.set(name, canvas);
  }
  host.hidden = otherViews.size === 0;
}

/** The anatomy pipeline's stages (`sim_core::anatomy::pipeline`) in words. */
const PREPARATION_STAGES = {
  start: 'starting',
  'read CT': 'reading the CT',
  'read masks': 'reading the segmentation',
  voxelize: 'building the body from its parameters',
  labels: 'labelling the structures',
  mesh: 'meshing the structures',
  interfaces: 'joining the surfaces of touching structures',
};

/** What the server says while a station's anatomy is prepared (503 `anatomy_preparing`). */
function preparingMessage(detail) {
  const r = detail.readiness || {};
  let text = `Preparing the anatomy (${detail.region || 'region'})`;
  if (typeof r.stage === 'string') text += `, ${PREPARATION_STAGES[r.stage] || r.stage}`;
  if (typeof r.fraction === 'number') text += `: ${Math.round(100 * r.fraction)} % done`;
  if (typeof r.remaining_s === 'number') text += `, about ${Math.max(1, Math.ceil(r.remaining_s))} s left`;
  return `${text}. The session starts by itself when it is ready.`;
}

/** Opens the attempt's session; while the anatomy is being prepared (or every session slot is
 * taken), shows why and asks again after the server's Retry-After (never a request held). */
async function startSession(attemptId) {
  for (;;) {
    try {
      return await api('POST', `/api/attempts/${attemptId}/session`);
    } catch (e) {
      if (!(e instanceof ApiError) || !['anatomy_preparing', 'at_capacity'].includes(e.code)) throw e;
      // Every live-session slot taken: the server's message says so, and the page asks again
      // after its Retry-After (sessions already running are not slowed by the wait).
      say(e.code === 'at_capacity' ? `${e.message}. Waiting for a free slot…` : preparingMessage(e.detail));
      // While the anatomy is prepared, ask every second so the progress shown keeps moving
      // (the answer is immediate and cheap); a full server is asked less often.
      const cap = e.code === 'anatomy_preparing' ? 1 : 10;
      const waitS = Math.min(cap, Math.max(1, Number(e.detail.retry_after_s) || 2));
      await new Promise((resolve) => setTimeout(resolve, 1000 * waitS));
    }
  }
}

async function openSession(attemptId, stationId) {
  say('');
  try {
    station = await api('GET', `/api/stations/${encodeURIComponent(stationId)}`);
    say('Starting the session…');
    const s = await startSession(attemptId);
    say('');
    if (live) live.close();
    show('session-view');
    $('session-title').textContent = station.title;
    // The station's goal and its criteria, in the rubric's order (safety ones marked).
    $('station-goal').textContent = (station.description || '').trim();
    $('station-steps').replaceChildren(...((station.rubric && station.rubric.criteria) || []).map((c) =>
      el('li', { textContent: c.critical ? `${c.description} (safety: a failure fails the attempt)` : c.description })));
    $('result').hidden = true;
    $('syringe').hidden = !(station.modalities || []).includes('contrast');
    $('injected').textContent = '0.00 mL';
    $('instrument').replaceChildren(...station.instruments.filter((i) => i.kind.includes('needle'))
      .map((i) => el('option', { value: i.id, textContent: `${i.id} (${i.kind})` })));
    // A new session shows its pose from the start: the client's pose is sent with the first
    // C-arm move; until a frame says otherwise the image is AP (the session's start).
    posesSent = [];
    shownPose = { orbital: 0, angular: 0 };
    lastAcquisitions = 0;
    lastViewName = 'AP';
    fluoroScreen.reset();
    live = new LiveSession(s.ws);
    // A new session starts with the beam off.
    $('live').setAttribute('aria-pressed', 'false');
    restartLiveTicks();
    us.reset(station);
    needle.reset(station);
    $('dose').textContent = '–';
    // Until the hello lists the session's views, the station's modalities say what to show.
    const listed = station.modalities || [];
    $('fluoro-viewer').hidden = !listed.includes('fluoroscopy');
    $('carm-controls').hidden = !listed.includes('fluoroscopy');
    window.__sim = { session: s, live, stats: live.stats, station, us, needle, screen: fluoroScreen, views: null };
    let drawn = 0;
    $('fluoro-wait').hidden = false;
    $('fluoro-wait').textContent = 'No image yet: press X or the Shot button for the first image.';
    let connectionLost = false;
    live.addEventListener('connection', (e) => {
      $('conn').textContent = e.detail.state;
      if (e.detail.state === 'closed' && !live.closed) {
        connectionLost = true;
        say('Connection lost: reconnecting by itself. Your commands are kept and sent again once it is back. If it does not come back within a minute, check the network and reload the page: the attempt resumes where it was.');
      }
    });
    live.addEventListener('hello', (e) => {
      $('conn').textContent = 'live';
      if (connectionLost) { connectionLost = false; say('Connection back: the session goes on where it was.'); }
      const views = e.detail.session.views || ['fluoroscopy'];
      $('session-mode').textContent = e.detail.session.mode === 'assessment'
        ? 'Assessment mode: no hints; the result comes in the debrief after you submit.'
        : 'Practice mode: hints such as "needle in the scan plane" are shown.';
      window.__sim.views = views;
      live.setVisible(views);
      showViews(views, e.detail.session.protocol);
      fluoroScreen.hello(live);
      // A resumed session: how many images it has is learnt from its next acknowledgement.
      if (e.detail.last_seq > 0) lastAcquisitions = null;
      $('pps').value = String(live.constant('fluoroscopy', 'default_pulse_rate_pps', 7.5));
    });
    live.addEventListener('frame', (e) => {
      const { bitmap, frame } = e.detail;
      if (frame.view === 'fluoroscopy') {
        needle.fluoroFrame(frame);
        fluoroScreen.frame(bitmap, frame, poseOfFrame(frame.inputSeq));
        $('fluoro-wait').hidden = true;
        // A draft (a cheap preview while the C-arm moves) says so until the full frame comes.
        $('fluoro-draft').hidden = !frame.draft;
      } else if (otherViews.has(frame.view)) {
        const canvas = otherViews.get(frame.view);
        canvas.width = frame.width;
        canvas.height = frame.height;
        canvas.getContext('2d').drawImage(bitmap, 0, 0);
        bitmap.close();
      } else if (!us.frame(frame, bitmap)) {
        bitmap.close();
      }
      drawn += 1;
      $('frame-count').textContent = String(drawn);
    });
    live.addEventListener('ack', (e) => {
      us.ack(e.detail);
      needle.ack(e.detail);
      const o = e.detail.outcome || {};
      if (o.depth_mm != null) $('depth').textContent = `${fmt(o.depth_mm, 1)} mm`;
      if (o.injected_ml != null) $('injected').textContent = `${fmt(o.injected_ml, 2)} mL`;
      if (o.dose) $('dose').textContent = doseWords(o.dose);
      // The C-arm's angles as the worker has them: after a reconnect (no pose of ours in
      // flight) they set the controls and the pose of the image on screen.
      // A new C-arm view is announced once the C-arm settles (simulator choice: 600 ms after
      // the last pose acknowledgement, so a drag is one announcement, not twenty).
      if (Array.isArray(o.carm_deg)) {
        const name = viewName({ orbital: o.carm_deg[0], angular: o.carm_deg[1] });
        clearTimeout(viewAnnounceTimer);
        if (name !== lastViewName) {
          viewAnnounceTimer = setTimeout(() => { $('announcer').textContent = `C-arm view: ${name}.`; }, 600);
          lastViewName = name;
        }
      }
      if (Array.isArray(o.carm_deg) && !posesSent.length && !poseTimer) {
        [pose.orbital, pose.angular] = o.carm_deg.map(Math.round);
        showPose();
      }
      if (Array.isArray(o.image_carm_deg) && !posesSent.length) {
        shownPose = { orbital: o.image_carm_deg[0], angular: o.image_carm_deg[1] };
      }
      // A new acquisition (a shot or a live run) is announced with the view it was taken in.
      if (o.acquisitions != null && o.acquisitions !== lastAcquisitions) {
        if (lastAcquisitions != null && Array.isArray(o.image_carm_deg)) {
          const [orbital, angular] = o.image_carm_deg;
          $('announcer').textContent = `Image acquired (${o.acquisitions} so far): ${viewName({ orbital, angular })}.`;
        }
        lastAcquisitions = o.acquisitions;
      }
      fluoroScreen.ack(o);
      // The rate the session runs at, as the fluoroscopy modality acknowledged it.
      if (o.pulse_rate_pps != null) { $('pps').value = String(o.pulse_rate_pps); window.__sim.pulseRate = o.pulse_rate_pps; }
      if (o.technique) showTechnique(o.technique);
      if (o.detector_mm != null) fullFieldMm = o.detector_mm;
      if (o.collimation !== undefined) showCollimation(o.collimation);
      if (o.field_mm != null) showField(o.field_mm);
      if ('recursive_filter' in o) {
        // A session recorded before the temporal chain has none: the control is off there.
        $('recursive-filter').disabled = o.recursive_filter == null;
        if (o.recursive_filter != null) $('recursive-filter').value = o.recursive_filter;
        if (window.__sim) window.__sim.recursiveFilter = o.recursive_filter;
      }
      if (o.detector != null) {
        // The station's image receptor: an image intensifier distorts and vignettes.
        $('detector').textContent = o.detector === 'image_intensifier' ? 'image intensifier' : 'flat panel';
        if (window.__sim) window.__sim.detector = o.detector;
      }
      if ('grid' in o) {
        // A session recorded before scatter has no grid: the control is off there.
        $('grid').disabled = o.grid == null;
        if (o.grid != null) $('grid').value = o.grid;
        if (window.__sim) window.__sim.grid = o.grid;
      }
    });
    live.addEventListener('commanderror', (e) => {
      needle.error(e.detail);
      logLine(`Not accepted (${e.detail.error.field}): ${e.detail.error.message}`);
    });
    live.addEventListener('notice', (e) => { logLine(e.detail.message); });
    live.addEventListener('ended', (e) => {
      $('conn').textContent = 'ended';
      say(`The session was closed: ${e.detail.reason}. Open the attempt again to continue.`);
    });
    live.addEventListener('technical_result', (e) => showResult(e.detail.result));
    live.addEventListener('technical_result_error', (e) => { say(`The result could not be stored: ${e.detail.message}`); });
    live.connect();
    // The keys work wherever the focus is (fluoro-view.js); the image takes it for the wheel
    // and the screen reader's description.
    $('fluoro').focus();
  } catch (e) {
    say(e.message);
  }
}

/** The session's dose estimate (fluoroscopy acks): air kerma at the reference point, kerma-area
 * product and fluoroscopy time. */
function doseWords(d) {
  return `air kerma ${fmt(d.air_kerma_mgy, 2)} mGy · KAP ${fmt(d.kerma_area_product_gycm2, 3)} Gy·cm² · fluoroscopy ${fmt(d.fluoro_time_s, 1)} s`;
}

function showResult(r) {
  if (window.__sim) window.__sim.result = r;
  $('result').hidden = false;
  const attemptId = window.__sim && window.__sim.session && window.__sim.session.attempt_id;
  $('result-debrief').hidden = !attemptId;
  if (attemptId) $('result-debrief').href = `/debrief.html?attempt=${encodeURIComponent(attemptId)}`;
  if (r.withheld) {
    // Assessment mode: the session carries no figures; the debrief has them.
    $('result-summary').textContent = 'Submitted. This station runs in assessment mode, so the session shows no figures: the debrief has the result. It now waits for faculty review.';
    $('result-criteria').hidden = true;
    $('result-notice').textContent = '';
    $('result-title').focus();
    return;
  }
  $('result-criteria').hidden = false;
  $('result-summary').textContent = `Technical result: ${outcomeWords(r.outcome)}; weighted score ${fmt(r.score)} (measured weight ${fmt(r.measured_weight_fraction)}). It now waits for faculty review.`;
  const criteria = (r.detail && r.detail.criteria) || [];
  $('result-criteria').tBodies[0].replaceChildren(...criteria.map((c) => el('tr', {},
    el('td', { textContent: c.description }),
    el('td', { textContent: c.value == null ? 'not measured' : `${fmt(c.value)} ${c.unit || ''}` }),
    el('td', { textContent: String(c.status).replace('_', ' ') + (c.critical_failure ? ' (critical)' : '') }))));
  $('result-notice').textContent = r.notice || '';
  $('result-title').focus();
}

setInterval(() => {
  if (!live) return;
  const l = live.latencyMs();
  $('latency').textContent = l == null ? '–' : `${l.toFixed(0)} ms`;
  $('fps').textContent = `${live.fps().toFixed(1)} /s`;
}, 500);

$('orbital').addEventListener('input', (e) => { pose.orbital = Number(e.target.value); sendPose(); });
$('angular').addEventListener('input', (e) => { pose.angular = Number(e.target.value); sendPose(); });
// C-arm buttons: 5 degrees a press, 1 with Shift (as the keys, fluoro-view.js).
for (const [id, o, a] of [['carm-rao', -1, 0], ['carm-lao', 1, 0], ['carm-cranial', 0, 1], ['carm-caudal', 0, -1]]) {
  $(id).addEventListener('click', (e) => { const d = e.shiftKey ? 1 : 5; rotate(o * d, a * d); });
}
// Technique: the committed spectra run from 40 to 120 kVp in 5 kVp steps; 80 kVp and 2 mA are
// the session's defaults (render_worker::session::fluoro).
$('kvp').replaceChildren(...Array.from({ length: 17 }, (_, i) => 40 + 5 * i).map((v) => el('option', { value: String(v), textContent: String(v), selected: v === 80 })));
function sendTechnique() {
  const ma = Number($('ma').value);
  if (live && ma >= 0.1 && ma <= 20) {
    // A technique set by hand turns the automatic brightness control off (as on a C-arm).
    $('abc').value = 'manual';
    live.send({ type: 'technique', kvp: Number($('kvp').value), ma });
  }
}
$('kvp').addEventListener('change', sendTechnique);
$('ma').addEventListener('change', sendTechnique);
// Collimator: blades closing symmetrically and an iris, in the detector plane (the session's
// `collimation` command); the image shows the shutters, the dose readout the smaller KAP.
function sendCollimation() {
  $('coll-width-out').textContent = $('coll-width').value;
  $('coll-height-out').textContent = $('coll-height').value;
  if (!live) return;
  const iris = $('coll-iris').value;
  live.send({ type: 'collimation', width_mm: Number($('coll-width').value), height_mm: Number($('coll-height').value), iris_diameter_mm: iris === '' ? null : Number(iris) });
}
/** The collimator as the session holds it (fluoroscopy acks; `null` for the open field), so a
 * resumed session's controls start where it is. */
function showCollimation(c) {
  if (window.__sim) window.__sim.collimation = c;
  const full = fullFieldMm || 300;
  for (const id of ['coll-width', 'coll-height']) $(id).max = String(full);
  $('coll-width').value = String(c ? c.width_mm : full);
  $('coll-height').value = String(c ? c.height_mm : full);
  $('coll-width-out').textContent = $('coll-width').value;
  $('coll-height-out').textContent = $('coll-height').value;
  const iris = c && c.iris_diameter_mm != null ? String(c.iris_diameter_mm) : '';
  if ([...$('coll-iris').options].some((o) => o.value === iris)) $('coll-iris').value = iris;
}
/** The magnification mode as the session holds it (fluoroscopy acks). */
function showField(fieldMm) {
  if (window.__sim) window.__sim.fieldMm = fieldMm;
  const fraction = String(fieldMm / (fullFieldMm || fieldMm));
  if ([...$('field').options].some((o) => o.value === fraction)) $('field').value = fraction;
}
$('coll-width').addEventListener('change', sendCollimation);
$('coll-height').addEventListener('change', sendCollimation);
$('coll-iris').addEventListener('change', sendCollimation);
$('coll-width').addEventListener('input', () => { $('coll-width-out').textContent = $('coll-width').value; });
$('coll-height').addEventListener('input', () => { $('coll-height-out').textContent = $('coll-height').value; });
// Magnification modes: fractions of the full detector field (the session's `magnification`
// command takes the field in mm; fluoroscopy acks name the detector's side).
let fullFieldMm = null;
$('field').addEventListener('change', (e) => {
  if (!live) return;
  live.send({ type: 'magnification', field_mm: Number(e.target.value) * (fullFieldMm || 300) });
});
// Live fluoroscopy's recursive filter (the session's `recursive_filter` command).
$('recursive-filter').addEventListener('change', (e) => {
  if (live) live.send({ type: 'recursive_filter', level: e.target.value });
});
// The anti-scatter grid (the session's `grid` command).
$('grid').addEventListener('change', (e) => {
  if (live) live.send({ type: 'grid', grid: e.target.value });
});
$('abc').addEventListener('change', (e) => {
  if (!live) return;
  if (e.target.value === 'manual') sendTechnique();
  else live.send({ type: 'brightness', curve: e.target.value });
});
/** The technique of the image on display (fluoroscopy acks) and what the next exposure uses:
 * the brightness control steps it after every frame. */
function showTechnique(t) {
  if (window.__sim) window.__sim.technique = t;
  $('abc').value = t.brightness;
  $('kvp').value = String(t.next_kvp);
  $('ma').value = String(t.next_ma);
  const limited = { curve: 'top of the curve', current: 'tube current', power: 'tube power', skin_rate: '88 mGy/min skin limit' };
  const parts = [`${t.kvp} kVp`, `${fmt(t.ma, 2)} mA`];
  if (t.pulse_rate_pps != null) parts.push(`${t.pulse_rate_pps} pulses/s`);
  if (t.detector_kerma_ngy != null) parts.push(`detector ${fmt(t.detector_kerma_ngy, 1)} nGy`);
  if (t.limited_by) parts.push(`held by the ${limited[t.limited_by] || t.limited_by}`);
  $('technique').textContent = parts.join(' · ');
}
$('shot').addEventListener('click', takeShot);
// Pulsed fluoroscopy: the learner's pulse rate (the session starts at the hello's
// `default_pulse_rate_pps`). While live runs the client ticks the session clock once per pulse,
// so a change that came between two pulses is imaged by the next one (ticks move only the
// logged clock; a pulse with nothing new renders nothing).
let liveTicker = null;
function pulsePeriodMs() { return 1000 / Number($('pps').value || 7.5); }
function restartLiveTicks() {
  if (liveTicker) { clearInterval(liveTicker); liveTicker = null; }
  if (!live || $('live').getAttribute('aria-pressed') !== 'true') return;
  liveTicker = setInterval(() => { if (live) live.send({ type: 'tick' }); }, pulsePeriodMs());
}
$('live').addEventListener('click', (e) => {
  if (!live) return;
  const on = e.target.getAttribute('aria-pressed') !== 'true';
  e.target.setAttribute('aria-pressed', String(on));
  live.send({ type: 'live', on });
  restartLiveTicks();
});
$('pps').addEventListener('change', () => {
  if (!live) return;
  live.send({ type: 'pulse_rate', pps: Number($('pps').value) });
  restartLiveTicks();
});

$('us-needle-place').addEventListener('click', () => us.placeInPlane($('instrument').value));

// Syringe: pressing the plunger starts an injection of the chosen volume at the chosen rate;
// releasing it stops. While fluid moves the client sends `tick`s, which move only the session's
// logged clock, so the contrast spreads (and live fluoroscopy shows it) in replayable steps.
// Ticks go on for the model's settling time after the release, then stop: an idle session
// sends nothing. Both numbers come from the hello (the contrast modality's `tick_ms` and
// `settle_ms`); the fallbacks only cover the moment before the first hello.
const tickMs = () => (live ? live.constant('contrast', 'tick_ms', 100) : 100);
const settleMs = () => (live ? live.constant('contrast', 'settle_ms', 2000) : 2000);
let ticker = null;
let tickUntil = 0;
function startTicks(ms) {
  tickUntil = Math.max(tickUntil, performance.now() + ms);
  if (ticker) return;
  ticker = setInterval(() => {
    if (!live || performance.now() > tickUntil) { clearInterval(ticker); ticker = null; return; }
    live.send({ type: 'tick' });
  }, tickMs());
}
function agentValue() {
  const a = $('agent').value;
  return a === 'diluted_contrast' ? { diluted_contrast: { stock_percent: 50 } } : a;
}
function pressPlunger(e) {
  if (!live || $('plunger').getAttribute('aria-pressed') === 'true') return;
  if (e) e.preventDefault();
  const volume = Number($('inject-volume').value);
  const rate = Number($('inject-rate').value);
  $('plunger').setAttribute('aria-pressed', 'true');
  live.send({ type: 'inject', agent: agentValue(), volume_ml: volume, rate_ml_per_s: rate });
  startTicks(1000 * volume / Math.max(rate, 1e-3) + settleMs());
}
function releasePlunger() {
  if (!live || $('plunger').getAttribute('aria-pressed') !== 'true') return;
  $('plunger').setAttribute('aria-pressed', 'false');
  live.send({ type: 'inject_stop' });
  tickUntil = performance.now() + settleMs();
  startTicks(settleMs());
}
$('plunger').addEventListener('pointerdown', pressPlunger);
$('plunger').addEventListener('pointerup', releasePlunger);
$('plunger').addEventListener('pointerleave', releasePlunger);
$('plunger').addEventListener('pointercancel', releasePlunger);
// Keyboard: hold Enter or Space on the plunger.
$('plunger').addEventListener('keydown', (e) => { if ((e.key === 'Enter' || e.key === ' ') && !e.repeat) pressPlunger(e); });
$('plunger').addEventListener('keyup', (e) => { if (e.key === 'Enter' || e.key === ' ') releasePlunger(); });
$('submit').addEventListener('click', () => live && live.send({ type: 'submit' }));
$('leave').addEventListener('click', () => { if (live) { live.close(); live = null; } learnerHome(openSession); });

// Keys, pointer and wheel on the fluoroscopy image: fluoro-view.js (FluoroScreen).


start();
