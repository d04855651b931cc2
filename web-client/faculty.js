// The faculty screen: dashboard links, the review queue, a review with the replay timeline, the
// authenticator set-up, approve or return.

import { api } from './api.js';
import { $, show, say, fmt, el, outcomeWords } from './ui.js';

/** The account shown (set by `facultyHome`). */
let me = null;

let reviewing = null;

/** The faculty screen for the logged-in `account` (the answer of /api/auth/me). */
export async function facultyHome(account) {
  me = account;
  show('faculty-view');
  $('review').hidden = true;
  $('totp-setup').hidden = me.mfa;
  try {
    // One dashboard link per course taught and station of the catalog.
    const [courses, stations] = await Promise.all([api('GET', '/api/courses'), api('GET', '/api/stations')]);
    const taught = courses.filter((c) => c.my_role === 'faculty' || me.user.role === 'admin');
    $('cohort-links').replaceChildren(...taught.flatMap((c) => stations.map((st) => el('li', {},
      el('a', { href: `/cohort.html?course=${encodeURIComponent(c.id)}&station=${encodeURIComponent(st.id)}`, textContent: `${c.code}: ${st.title}` })))));
    const queue = await api('GET', '/api/reviews?state=submitted');
    $('queue').tBodies[0].replaceChildren(...queue.map((a) => {
      const b = el('button', { type: 'button', textContent: 'Review' });
      b.setAttribute('aria-label', `Review the attempt of ${a.learner_name} at ${a.station_id}`);
      b.addEventListener('click', () => openReview(a));
      return el('tr', {}, el('td', { textContent: a.learner_name }), el('td', { textContent: a.station_id }),
        el('td', { textContent: a.state }), el('td', { textContent: `${outcomeWords(a.latest_outcome)} (${fmt(a.latest_score)})` }),
        el('td', { textContent: provenanceWords(a.latest_source, a.latest_replay_check) }), el('td', {}, b));
    }));
  } catch (e) {
    say(e.message);
  }
}

$('totp-enroll').addEventListener('click', async () => {
  try {
    const t = await api('POST', '/api/auth/totp/enroll');
    $('totp-secret').textContent = t.secret_base32;
    $('totp-secret-box').hidden = false;
    $('totp-confirm-code').focus();
  } catch (e) { say(e.message); }
});
$('totp-confirm').addEventListener('click', async () => {
  try {
    await api('POST', '/api/auth/totp/confirm', { code: $('totp-confirm-code').value.trim() });
    // Confirming counts as a login with a code for this session; later logins ask for one.
    me.mfa = true;
    $('totp-secret-box').hidden = true;
    await facultyHome(me);
    say('Authenticator set up. Future logins ask for a code.');
  } catch (e) { say(e.message); }
});

// Where a technical result came from and what replaying its log showed, in words for faculty.
const SOURCE_WORDS = { server: 'computed by the simulation', client: 'reported by a client (legacy, not replayable)' };
const CHECK_WORDS = {
  pending: 'replay check pending',
  identical: 'replay reproduces it exactly',
  differs: 'REPLAY DIFFERS: do not trust this result',
  unavailable: 'no log to replay',
};
function provenanceWords(source, check) {
  if (!source) return '—';
  return `${SOURCE_WORDS[source] || source}; ${CHECK_WORDS[check] || check || 'replay check pending'}`;
}

function setStep(k) {
  if (!reviewing) return;
  $('timeline').value = String(k);
  const steps = reviewing.replay.timeline;
  $('timeline-out').textContent = k === 0 ? 'start' : `${k} / ${steps.length}: ${steps[k - 1].command.type} at ${(steps[k - 1].t_ms / 1000).toFixed(1)} s`;
  for (const [i, li] of [...$('timeline-list').children].entries()) {
    if (i + 1 === k) li.setAttribute('aria-current', 'step'); else li.removeAttribute('aria-current');
  }
  $('replay-frame').src = `/api/attempts/${reviewing.attempt.id}/replay/frame?step=${k}`;
  // An ultrasound station: the B-mode image of the same step beside it (none before the
  // probe is on the skin: the server answers 204 and the image stays hidden).
  if (reviewing.ultrasound) $('replay-us-frame').src = `/api/attempts/${reviewing.attempt.id}/replay/frame?step=${k}&view=ultrasound`;
}

async function openReview(a) {
  say('');
  try {
    const [replay, detail, station] = await Promise.all([api('GET', `/api/attempts/${a.id}/replay`), api('GET', `/api/attempts/${a.id}`),
      api('GET', `/api/stations/${encodeURIComponent(a.station_id)}`)]);
    const ultrasound = (station.modalities || []).includes('ultrasound');
    reviewing = { attempt: a, replay, detail, ultrasound };
    $('replay-us-frame').hidden = true;
    $('review').hidden = false;
    $('review-title').textContent = `${a.learner_name} — ${a.station_id}`;
    $('review-debrief').href = `/debrief.html?attempt=${encodeURIComponent(a.id)}`;
    $('timeline').max = String(replay.timeline.length);
    $('timeline-list').replaceChildren(...replay.timeline.map((e, i) => {
      const b = el('button', { type: 'button', textContent: `${e.command.type} (${(e.t_ms / 1000).toFixed(1)} s)` });
      b.addEventListener('click', () => setStep(i + 1));
      return el('li', {}, b);
    }));
    $('replay-check').textContent = replay.identical
      ? 'Replay reproduces the recorded measurements, score, final state and final image exactly.'
      : 'Replay differs from the record (see the server log).';
    const r = detail.results[detail.results.length - 1];
    $('review-result').replaceChildren(el('p', { textContent: r ? `Technical result: ${outcomeWords(r.outcome)}, score ${fmt(r.score)}.` : 'No technical result.' }),
      el('p', { className: 'notice', textContent: detail.notice || '' }));
    $('review-provenance').textContent = r
      ? `Source: ${provenanceWords(r.source, r.replay_check && r.replay_check.verdict)}.`
      : '';
    setStep(replay.timeline.length);
    $('review-title').focus();
  } catch (e) {
    say(e.message);
  }
}

$('timeline').addEventListener('input', (e) => setStep(Number(e.target.value)));
$('review-form').addEventListener('submit', async (ev) => {
  ev.preventDefault();
  if (!reviewing) return;
  const decision = ev.submitter ? ev.submitter.value : 'approve';
  try {
    await api('POST', `/api/attempts/${reviewing.attempt.id}/review`, { decision, comment: $('review-comment').value });
    say(decision === 'approve' ? 'Approved.' : 'Returned to the learner.');
    $('review-comment').value = '';
    reviewing = null;
    await facultyHome(me);
  } catch (e) {
    say(e.message);
    if (e.status === 403 && /TOTP/i.test(e.message)) $('totp-setup').hidden = false;
  }
});

$('replay-us-frame').addEventListener('load', () => { $('replay-us-frame').hidden = false; });
$('replay-us-frame').addEventListener('error', () => { $('replay-us-frame').hidden = true; });
