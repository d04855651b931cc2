// The learner's stations screen: the courses they are enrolled in, the stations, their attempts
// (continue one, or open its debrief) and a new attempt.

import { api } from './api.js';
import { $, show, say, fmt, el, outcomeWords } from './ui.js';

/** The learner's screen; `openSession(attemptId, stationId)` opens an attempt's session. */
export async function learnerHome(openSession) {
  show('learner-view');
  const [courses, stations, attempts] = await Promise.all([
    api('GET', '/api/courses'), api('GET', '/api/stations'), api('GET', '/api/attempts'),
  ]);
  const sel = $('course-select');
  sel.replaceChildren(...courses.filter((c) => c.my_role === 'learner').map((c) => el('option', { value: c.id, textContent: `${c.code} — ${c.title}` })));
  $('station-list').replaceChildren(...stations.map((s) => {
    const b = el('button', { type: 'button', textContent: 'Start attempt' });
    b.setAttribute('aria-label', `Start attempt at ${s.title}`);
    b.dataset.station = s.id;
    b.addEventListener('click', () => newAttempt(s.id, openSession));
    return el('li', {}, el('h3', { textContent: s.title }), el('p', { textContent: `${s.modalities.join(', ')} · ${s.criteria} criteria` }), b);
  }));
  const rows = attempts.map((a) => {
    const td = el('td');
    if (a.state === 'in_progress' || a.state === 'returned') {
      const b = el('button', { type: 'button', textContent: 'Continue' });
      b.setAttribute('aria-label', `Continue the attempt at ${a.station_id}`);
      b.addEventListener('click', () => openSession(a.id, a.station_id));
      td.append(b);
    }
    if (a.latest_outcome) {
      const link = el('a', { href: `/debrief.html?attempt=${encodeURIComponent(a.id)}`, textContent: 'Debrief' });
      link.setAttribute('aria-label', `Debrief of the attempt at ${a.station_id}`);
      td.append(' ', link);
    }
    return el('tr', {}, el('td', { textContent: a.station_id }), el('td', { textContent: a.state.replace('_', ' ') }),
      el('td', { textContent: a.latest_outcome ? `${outcomeWords(a.latest_outcome)} (${fmt(a.latest_score)})` : '–' }),
      el('td', { textContent: new Date(a.updated_at).toLocaleString() }), td);
  });
  $('my-attempts').tBodies[0].replaceChildren(...rows);
  // An LTI launch lands on /?course=...&station=...: preselect the course, point at the station.
  const linked = new URLSearchParams(location.search);
  if (linked.get('course')) sel.value = linked.get('course');
  const station = linked.get('station') && $('station-list').querySelector(`button[data-station="${CSS.escape(linked.get('station'))}"]`);
  if (station) station.focus();
}

async function newAttempt(stationId, openSession) {
  try {
    const courseId = $('course-select').value;
    if (!courseId) { say('You are not enrolled as a learner in any course.'); return; }
    const a = await api('POST', '/api/attempts', { course_id: courseId, station_id: stationId });
    await openSession(a.id, stationId);
  } catch (e) {
    say(e.message);
  }
}
