// The cohort dashboard's data (web-client/cohort-model.js): addresses with their filters, chart
// series from an API answer, the reference band, table rows and the competency words.
// Run: node --test web-client/tests/unit/
import { test } from 'node:test';
import assert from 'node:assert/strict';
import * as m from '../../cohort-model.js';

const COURSE = '11111111-2222-3333-4444-555555555555';
const ANN = 'aaaaaaaa-0000-0000-0000-000000000001';
const BOB = 'bbbbbbbb-0000-0000-0000-000000000002';

function attempt(id, n, score, extra = {}) {
  return {
    attempt_id: id, n, created_at: '2026-01-01T00:00:00Z', state: 'submitted', mode: 'practice',
    score, outcome: score == null ? null : (score >= 0.75 ? 'met' : 'not_met'),
    air_kerma_mgy: 2 + n, kerma_area_product_gycm2: 0.1 * n, fluoro_time_s: 10 * n,
    critical_failures: [], criteria: {}, ...extra,
  };
}

/** An answer shaped like `GET /api/courses/{id}/cohort` (records::cohort::Cohort). */
function cohort() {
  return {
    course_id: COURSE, station_id: 'demo-station', station_title: 'Demo station', pass_threshold: 0.75,
    attempts: 7, scored_attempts: 6,
    criteria: [
      { id: 'tip_at_target', description: 'Tip distance', critical: false, met: 5, not_met: 1, missing: 0, pass_rate: 5 / 6 },
      { id: 'no_dural_puncture', description: 'No dural puncture', critical: true, met: 5, not_met: 1, missing: 0, pass_rate: 5 / 6 },
      { id: 'image_economy', description: 'Few images', critical: false, met: 0, not_met: 0, missing: 6, pass_rate: null },
    ],
    learners: [
      {
        learner_id: ANN, email: 'ann@example.org', name: 'Ann Lee',
        attempts: [attempt('a1', 1, 0.5), attempt('a2', 2, 0.9), attempt('a3', 3, 0.95), attempt('a4', 4, 1.0)],
        competency: { status: 'competent', reason: 'the last 3 ...', judged: ['a2', 'a3', 'a4'] },
      },
      {
        learner_id: BOB, email: 'bob@example.org', name: '',
        attempts: [attempt('b1', 1, 0.9), attempt('b2', 2, 0.9, { critical_failures: ['no_dural_puncture'], outcome: 'not_met' }),
          attempt('b3', 3, null, { state: 'in_progress' })],
        competency: { status: 'too_few_attempts', reason: '2 scored attempt(s)', judged: ['b1', 'b2'] },
      },
    ],
    band: [
      { n: 1, learners: 2, p25: 0.6, median: 0.7, p75: 0.8 },
      { n: 2, learners: 2, p25: 0.9, median: 0.9, p75: 0.9 },
      { n: 3, learners: 1, p25: 0.95, median: 0.95, p75: 0.95 },
    ],
    notice: 'Technical results ...',
  };
}

test('page parameters are read, trimmed, and an unknown mode is dropped', () => {
  assert.deepEqual(m.pageParams(`?course=${COURSE}&station=demo-station`),
    { course: COURSE, station: 'demo-station', learner: '', mode: '' });
  assert.deepEqual(m.pageParams('?course=%20x%20&mode=exam').course, 'x');
  assert.equal(m.pageParams('?mode=exam').mode, '');
  assert.equal(m.pageParams('?mode=assessment').mode, 'assessment');
  assert.equal(m.pageSearch({ course: 'c', station: 's', learner: '', mode: 'practice' }), '?course=c&station=s&mode=practice');
  assert.equal(m.pageSearch({}), '');
});

test('the JSON and CSV addresses carry the same filters, encoded', () => {
  const f = { station: 'demo station&x', learner: ANN, mode: 'assessment' };
  const json = m.cohortUrl(COURSE, f);
  const csv = m.csvUrl(COURSE, f);
  assert.equal(json, `/api/courses/${COURSE}/cohort?station_id=demo+station%26x&learner_id=${ANN}&mode=assessment`);
  assert.equal(csv, json.replace('/cohort?', '/cohort.csv?'));
  // Empty filters are left out: the server refuses an empty learner id.
  assert.equal(m.csvUrl(COURSE, { station: 'demo-station', learner: '', mode: '' }),
    `/api/courses/${COURSE}/cohort.csv?station_id=demo-station`);
  const q = new URLSearchParams(m.cohortQuery(f));
  assert.equal(q.get('station_id'), 'demo station&x');
});

test('criteria series split safety criteria from the others and keep unmeasured ones empty', () => {
  const s = m.criteriaSeries(cohort());
  assert.deepEqual(s.x, [1, 2, 3]);
  assert.deepEqual(s.safety, [null, 5 / 6, null]);
  assert.deepEqual(s.other, [5 / 6, null, null]);
  assert.deepEqual(s.labels, ['tip_at_target', 'no_dural_puncture (safety)', 'image_economy']);
  const rows = m.criteriaRows(cohort());
  assert.equal(rows.length, 3);
  assert.deepEqual(rows.map((r) => [r.kind, r.rate]), [['other', '83 %'], ['safety', '83 %'], ['other', 'not measured']]);
});

test('learning curves: band first, then each learner by scored-attempt number', () => {
  const c = cohort();
  const data = m.curveSeries(c.learners, c.band);
  // x runs to the longest of the band (3) and the learners (Ann: 4 scored attempts).
  assert.deepEqual(data[0], [1, 2, 3, 4]);
  assert.deepEqual(data[1], [0.6, 0.9, 0.95, null]);
  assert.deepEqual(data[2], [0.7, 0.9, 0.95, null]);
  assert.deepEqual(data[3], [0.8, 0.9, 0.95, null]);
  assert.deepEqual(data[4], [0.5, 0.9, 0.95, 1.0]);
  // Bob's unscored third attempt is no point.
  assert.deepEqual(data[5], [0.9, 0.9, null, null]);
  assert.equal(data.length, 6);
  // No data at all: an empty x.
  assert.deepEqual(m.curveSeries([], []), [[], [], [], []]);
  const rows = m.curveRows(c.learners);
  assert.equal(rows.length, 6);
  assert.deepEqual(rows[5], { learner: 'bob@example.org', k: 2, n: 2, score: '0.90' });
  assert.deepEqual(m.bandRows(c.band)[0], { k: 1, learners: 2, p25: '0.60', median: '0.70', p75: '0.80' });
});

test('scored-attempt numbers skip unscored attempts but keep the attempt number', () => {
  const l = { attempts: [attempt('x1', 1, null), attempt('x2', 2, 0.8)] };
  assert.deepEqual(m.scoredPoints(l), [{ k: 1, n: 2, score: 0.8 }]);
});

test('dose series put a gap between learners and name each attempt', () => {
  const { data, ticks } = m.doseSeries(cohort().learners);
  assert.deepEqual(data[0], [1, 2, 3, 4, 5, 6, 7, 8]);
  assert.deepEqual(data[1], [3, 4, 5, 6, null, 3, 4, 5]);
  assert.equal(data[2][4], null);
  assert.deepEqual(data[3].slice(5), [10, 20, 30]);
  assert.equal(ticks.get(1), 'AL 1');
  assert.equal(ticks.get(8), 'B 3');
  assert.equal(ticks.has(5), false);
  const rows = m.doseRows(cohort().learners);
  assert.equal(rows.length, 7);
  assert.deepEqual(rows[6], { learner: 'bob@example.org', n: 3, mode: 'practice', state: 'in progress', score: '–',
    outcome: 'not scored yet', kerma: '5.00', kap: '0.300', time: '30.0' });
});

test('competency words: a safety failure is named, and is not confused with a low score', () => {
  const c = cohort();
  const ann = m.competencyWords(c.learners[0]);
  assert.equal(ann.label, 'Competent (technical criteria)');
  assert.equal(ann.safety, false);
  assert.deepEqual(ann.judgedNumbers, [2, 3, 4]);
  const bob = m.competencyWords(c.learners[1]);
  assert.equal(bob.label, 'Too few scored attempts');
  assert.equal(bob.safety, false, 'too few attempts stays too few, whatever failed');
  const unsafe = { ...c.learners[1], competency: { status: 'not_yet', reason: 'attempt 2 failed ...', judged: ['b1', 'b2'] } };
  const w = m.competencyWords(unsafe);
  assert.equal(w.label, 'Not yet: safety criterion failed');
  assert.equal(w.safety, true);
  assert.deepEqual(w.failed, ['no_dural_puncture']);
  const low = { ...c.learners[0], competency: { status: 'not_yet', reason: 'attempt 1 was not_met', judged: ['a1', 'a2', 'a3'] } };
  assert.deepEqual([m.competencyWords(low).label, m.competencyWords(low).safety], ['Not yet', false]);
});

test('series styles differ by dash and marker as well as colour', () => {
  const styles = Array.from({ length: 6 }, (_, i) => m.seriesStyle(i));
  assert.equal(new Set(styles.map((s) => JSON.stringify(s.dash))).size, 6);
  assert.equal(new Set(styles.map((s) => s.stroke)).size, 6);
  assert.notEqual(styles[0].pointSize, styles[1].pointSize);
  assert.equal(m.dashWords([]), 'solid line');
  assert.equal(m.dashWords([2, 4]), 'dotted line');
  assert.equal(m.dashWords([10, 5]), 'dashed line');
  assert.equal(m.dashWords([12, 4, 2, 4]), 'dash-dot line');
  assert.ok(!m.DASHES.some((d) => JSON.stringify(d) === JSON.stringify(m.MEDIAN_DASH)), 'the median dash is its own');
});

test('numbers, rates and names read well', () => {
  assert.equal(m.fmt(null), '–');
  assert.equal(m.fmt(0.125, 1), '0.1');
  assert.equal(m.percent(null), 'not measured');
  assert.equal(m.percent(1), '100 %');
  assert.equal(m.learnerLabel({ name: '', email: 'x@y' }), 'x@y');
  assert.equal(m.initials('learner2@demo.invalid'), 'L');
  assert.equal(m.initials('Demo Learner Two'), 'DLT');
  assert.match(m.curveSummary([{}], [{}, {}], 0.75), /1 learner, .*2 attempt numbers.*0\.75/);
  assert.equal(m.outcomeWords('met'), 'technical criteria met');
});
