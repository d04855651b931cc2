// The cohort dashboard's data, without the DOM: the page's parameters and the API and CSV URLs
// they give, the series the charts draw (criteria pass rates, learning curves against the
// cohort's band, dose and fluoroscopy time per attempt), the rows of the data tables that
// follow each chart, and the competency judgement in words. `cohort.js` puts them on the page.

/** Station modes (`records::modes::StationMode`'s wire spelling). */
export const MODES = ['practice', 'assessment'];

/** Line colours: the Okabe-Ito palette (Okabe and Ito 2008, "Color Universal Design"), chosen
 * to stay apart under the common colour-vision deficiencies; black is left out (it is the
 * dark theme's background). */
export const PALETTE = ['#0072B2', '#D55E00', '#009E73', '#CC79A7', '#E69F00', '#56B4E9', '#F0E442'];

/** Dash patterns in CSS pixels ([] = solid), so that lines differ by shape as well as colour.
 * Simulator choice: patterns far enough apart to tell at a 2 px line width. */
export const DASHES = [[], [10, 5], [2, 4], [12, 4, 2, 4], [6, 3, 6, 9], [2, 8]];

/** Point marker sizes in CSS pixels, alternating so neighbouring learners also differ by marker.
 * Simulator choice: 6 px points are visible at a 2 px line, 9 px stand out from them. */
export const POINT_SIZES = [6, 9];

/** The dash of the cohort's median line. Simulator choice: a long dash unlike any learner's. */
export const MEDIAN_DASH = [16, 6];

/** What the page's address names: `course`, `station`, `learner`, `mode` (empty when absent). */
export function pageParams(search) {
  const q = new URLSearchParams(search);
  const get = (k) => (q.get(k) || '').trim();
  const mode = get('mode');
  return { course: get('course'), station: get('station'), learner: get('learner'), mode: MODES.includes(mode) ? mode : '' };
}

/** The page's own address for these choices (empty ones left out), for `history.replaceState`. */
export function pageSearch({ course, station, learner, mode }) {
  const q = new URLSearchParams();
  if (course) q.set('course', course);
  if (station) q.set('station', station);
  if (learner) q.set('learner', learner);
  if (mode) q.set('mode', mode);
  const s = q.toString();
  return s ? `?${s}` : '';
}

/** The cohort filter's query (`records::cohort::CohortFilter`): the station, and the learner
 * and mode when chosen. */
export function cohortQuery({ station, learner, mode }) {
  const q = new URLSearchParams({ station_id: station });
  if (learner) q.set('learner_id', learner);
  if (mode) q.set('mode', mode);
  return q.toString();
}

/** The cohort's JSON address. */
export function cohortUrl(course, filters) {
  return `/api/courses/${encodeURIComponent(course)}/cohort?${cohortQuery(filters)}`;
}

/** The CSV export's address, with the same filters as the page. */
export function csvUrl(course, filters) {
  return `/api/courses/${encodeURIComponent(course)}/cohort.csv?${cohortQuery(filters)}`;
}

/** A number with `digits` decimals, or an en dash when absent. */
export function fmt(v, digits = 2) {
  return v == null || Number.isNaN(Number(v)) ? '–' : Number(v).toFixed(digits);
}

/** A rate (0 to 1) as a whole percentage, or "not measured". */
export function percent(rate) {
  return rate == null ? 'not measured' : `${Math.round(rate * 100)} %`;
}

/** A learner's name for tables and legends: the name, else the e-mail. */
export function learnerLabel(l) {
  return l.name || l.email;
}

/** The style of the `i`th learner's line: colour, dash and point size all cycle, on periods
 * 7, 6 and 2, so two learners share all three only 42 learners apart. */
export function seriesStyle(i) {
  return {
    stroke: PALETTE[i % PALETTE.length],
    dash: DASHES[i % DASHES.length],
    pointSize: POINT_SIZES[i % POINT_SIZES.length],
  };
}

/** A dash pattern in words, for the data tables and legends. */
export function dashWords(dash) {
  if (!dash.length) return 'solid line';
  if (dash.length > 2) return 'dash-dot line';
  return dash[0] <= 2 ? 'dotted line' : 'dashed line';
}

/** Outcome words, as on the attempt's own page. */
export function outcomeWords(outcome) {
  return { met: 'technical criteria met', not_met: 'technical criteria not met', incomplete: 'incomplete (some measurements missing)' }[outcome]
    || (outcome || 'not scored yet');
}

/** A learner's competency in words: `label` (the status), `safety` (true when "not yet"
 * because a judged attempt failed a safety criterion, which no score offsets), the safety
 * criteria failed, and the judged attempts' numbers. */
export function competencyWords(learner) {
  const c = learner.competency;
  const judged = c.judged.map((id) => learner.attempts.find((a) => a.attempt_id === id)).filter(Boolean);
  const failed = [...new Set(judged.flatMap((a) => a.critical_failures || []))];
  const safety = c.status === 'not_yet' && failed.length > 0;
  const label = {
    competent: 'Competent (technical criteria)',
    not_yet: safety ? 'Not yet: safety criterion failed' : 'Not yet',
    too_few_attempts: 'Too few scored attempts',
  }[c.status] || c.status;
  return { status: c.status, label, safety, failed, judgedNumbers: judged.map((a) => a.n), reason: c.reason };
}

/** The criteria chart: x = 1..N (criterion order), the pass rate (0 to 1) of the safety
 * criteria in one series and of the others in another (null where the criterion is of the
 * other kind or never measured), and the axis labels. */
export function criteriaSeries(cohort) {
  const cs = cohort.criteria;
  return {
    x: cs.map((_, i) => i + 1),
    safety: cs.map((c) => (c.critical ? c.pass_rate : null)),
    other: cs.map((c) => (c.critical ? null : c.pass_rate)),
    labels: cs.map((c) => (c.critical ? `${c.id} (safety)` : c.id)),
  };
}

/** Rows of the criteria table. */
export function criteriaRows(cohort) {
  return cohort.criteria.map((c) => ({
    id: c.id, description: c.description, kind: c.critical ? 'safety' : 'other',
    met: c.met, not_met: c.not_met, missing: c.missing, rate: percent(c.pass_rate),
  }));
}

/** A learner's scored attempts in order: `k` (1 = the first scored one, the band's numbering),
 * the attempt number `n` and the score. */
export function scoredPoints(learner) {
  return learner.attempts.filter((a) => a.score != null).map((a, i) => ({ k: i + 1, n: a.n, score: a.score }));
}

/** The learning-curve chart's data, for uPlot: x = scored-attempt numbers 1..K (K the longest
 * of the band and the learners), then the band's p25, median and p75, then one score series
 * per learner (null where a learner has no such attempt). `band` is the cohort's reference
 * band (the whole cohort's, also when the learners are filtered). */
export function curveSeries(learners, band) {
  const kMax = Math.max(0, ...band.map((b) => b.n), ...learners.map((l) => scoredPoints(l).length));
  const x = Array.from({ length: kMax }, (_, i) => i + 1);
  const at = (k, key) => {
    const b = band.find((p) => p.n === k);
    return b ? b[key] : null;
  };
  const data = [x, x.map((k) => at(k, 'p25')), x.map((k) => at(k, 'median')), x.map((k) => at(k, 'p75'))];
  for (const l of learners) {
    const pts = scoredPoints(l);
    data.push(x.map((k) => (pts[k - 1] ? pts[k - 1].score : null)));
  }
  return data;
}

/** Rows of the learning-curve table: one per learner and scored attempt. */
export function curveRows(learners) {
  return learners.flatMap((l) => scoredPoints(l).map((p) => ({ learner: learnerLabel(l), k: p.k, n: p.n, score: fmt(p.score) })));
}

/** Rows of the band table. */
export function bandRows(band) {
  return band.map((b) => ({ k: b.n, learners: b.learners, p25: fmt(b.p25), median: fmt(b.median), p75: fmt(b.p75) }));
}

/** The dose chart's data, for uPlot: x = positions 1..M over every attempt, learner after
 * learner with one empty position between learners (so no line joins two learners), then air
 * kerma (mGy), kerma-area product (Gy cm^2) and fluoroscopy time (s); `ticks` names each
 * attempt's position (learner and attempt number). */
export function doseSeries(learners) {
  const x = [], kerma = [], kap = [], time = [], ticks = new Map();
  let pos = 0;
  learners.forEach((l, li) => {
    if (li > 0) {
      pos += 1;
      x.push(pos); kerma.push(null); kap.push(null); time.push(null);
    }
    for (const a of l.attempts) {
      pos += 1;
      x.push(pos);
      kerma.push(a.air_kerma_mgy ?? null);
      kap.push(a.kerma_area_product_gycm2 ?? null);
      time.push(a.fluoro_time_s ?? null);
      ticks.set(pos, `${initials(learnerLabel(l))} ${a.n}`);
    }
  });
  return { data: [x, kerma, kap, time], ticks };
}

/** Rows of the dose table: one per attempt. */
export function doseRows(learners) {
  return learners.flatMap((l) => l.attempts.map((a) => ({
    learner: learnerLabel(l), n: a.n, mode: a.mode, state: a.state.replace(/_/g, ' '),
    score: fmt(a.score), outcome: outcomeWords(a.outcome),
    kerma: fmt(a.air_kerma_mgy), kap: fmt(a.kerma_area_product_gycm2, 3), time: fmt(a.fluoro_time_s, 1),
  })));
}

/** Short initials of a name (or an e-mail's local part), for crowded axis labels. */
export function initials(label) {
  const words = String(label).split('@')[0].split(/[\s._-]+/).filter(Boolean);
  return words.map((w) => w[0].toUpperCase()).join('').slice(0, 3) || '?';
}

/** A one-sentence summary of a chart for its `aria-label`. */
export function curveSummary(learners, band, passThreshold) {
  const n = learners.length;
  return `Line chart of the score per scored attempt for ${n} learner${n === 1 ? '' : 's'}, `
    + `against the cohort's band over ${band.length} attempt number${band.length === 1 ? '' : 's'} `
    + `(quartiles shaded, median dashed); pass threshold ${fmt(passThreshold)}. The table below holds the values.`;
}
