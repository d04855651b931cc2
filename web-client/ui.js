// What every screen of the main page shares: element lookup, switching screens, the message
// line, number formatting, building elements and the words for technical outcomes.

export const $ = (id) => document.getElementById(id);
const VIEWS = ['login-view', 'learner-view', 'session-view', 'faculty-view'];

/** Shows screen `id` (one of the page's views) and moves the focus to its heading. */
export function show(id) {
  for (const v of VIEWS) $(v).hidden = v !== id;
  const heading = $(id).querySelector('h2');
  if (heading) { heading.tabIndex = -1; heading.focus(); }
}

/** The page's message line (role="alert"). */
export function say(text) {
  $('message').textContent = text || '';
}

export function fmt(v, digits = 2) {
  return v == null ? '–' : Number(v).toFixed(digits);
}

export function el(tag, props = {}, ...children) {
  const e = document.createElement(tag);
  Object.assign(e, props);
  for (const c of children) e.append(c);
  return e;
}

/** Plain words for rubric outcomes: a technical statement, never a verdict on the person. */
export function outcomeWords(outcome) {
  return { met: 'technical criteria met', not_met: 'technical criteria not met', incomplete: 'incomplete (some measurements missing)' }[outcome] || (outcome || 'not scored yet');
}
