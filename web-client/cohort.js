// The faculty cohort dashboard (`cohort.html?course=<uuid>&station=<id>`): per course and
// station, the pass rate per criterion, each learner's learning curve against the cohort's
// band, dose and fluoroscopy time per attempt, and the competency judgement, each chart followed
// by its data table; filters by learner and mode with a CSV export of the same attempts; and how
// each station runs in the course (practice or assessment), set here.
//
// Charts are drawn by the vendored uPlot (`vendor/uplot/`, loaded by a classic script before
// this module, as the global `uPlot`). The data behind them comes from `cohort-model.js`.

import { api, setCsrf, ApiError } from './api.js';
import * as m from './cohort-model.js';

const $ = (id) => document.getElementById(id);

/** Chart height in CSS pixels. Simulator choice: tall enough for ten score gridlines. */
const CHART_HEIGHT_PX = 300;
/** Narrowest chart in CSS pixels. Simulator choice: a phone's width less the page margins. */
const CHART_MIN_WIDTH_PX = 300;
/** Height of the criteria chart's x axis in CSS pixels, room for rotated criterion ids.
 * Simulator choice: fits about 26 characters at -35 degrees. */
const CRITERIA_AXIS_PX = 130;
/** Side of the hatch tile of the safety criteria's bars, CSS pixels. Simulator choice. */
const HATCH_PX = 8;
/** Share of the band between quartiles that is filled (alpha of the muted text colour).
 * Simulator choice: visible in both themes without hiding the lines behind it. */
const BAND_ALPHA_HEX = '40';
/** Point size of the dose chart's markers, CSS pixels. Simulator choice: visible beside a
 * 2 px line. */
const DOSE_POINT_PX = 7;
/** Top of the dose axes as a multiple of the largest value. Simulator choice: 10 % headroom
 * keeps the highest point off the chart's edge. */
const AXIS_HEADROOM = 1.1;
/** Milliseconds to wait after the last window resize before resizing the charts. Simulator
 * choice: one resize per drag rather than one per frame. */
const RESIZE_DEBOUNCE_MS = 150;

const page = {
  me: null,
  courses: [],
  stations: [],
  charts: [],
  cohort: null,
  reference: null,
  loadSeq: 0,
  loadFailed: false,
};

function el(tag, props = {}, ...children) {
  const e = document.createElement(tag);
  Object.assign(e, props);
  for (const c of children) e.append(c);
  return e;
}

function say(text) {
  $('message').textContent = text || '';
}

function status(text) {
  $('status').textContent = text || '';
}

/** The colours of the page's theme (`styles.css`'s custom properties). */
function theme() {
  const css = getComputedStyle(document.documentElement);
  const v = (name, fallback) => css.getPropertyValue(name).trim() || fallback;
  return { fg: v('--fg', '#1b1d21'), muted: v('--muted', '#555b64'), border: v('--border', '#c3c8d0'),
    bg: v('--bg', '#ffffff'), accent: v('--accent', '#1f5fcc') };
}

function chartWidth(container) {
  return Math.max(CHART_MIN_WIDTH_PX, Math.floor(container.clientWidth || container.parentElement.clientWidth || 600));
}

function axis(t, extra = {}) {
  return { stroke: t.fg, grid: { stroke: t.border, width: 1 }, ticks: { stroke: t.border, width: 1 }, ...extra };
}

/** A repeating diagonal hatch in `colour` (the safety criteria's bars, told apart by texture
 * as well as colour). */
function hatch(ctx, colour) {
  const size = Math.round(HATCH_PX * devicePixelRatio);
  const tile = document.createElement('canvas');
  tile.width = size;
  tile.height = size;
  const c = tile.getContext('2d');
  c.fillStyle = colour + '55';
  c.fillRect(0, 0, size, size);
  c.strokeStyle = colour;
  c.lineWidth = Math.max(1, devicePixelRatio * 1.5);
  c.beginPath();
  c.moveTo(0, size);
  c.lineTo(size, 0);
  c.moveTo(-size / 2, size / 2);
  c.lineTo(size / 2, -size / 2);
  c.moveTo(size / 2, size * 1.5);
  c.lineTo(size * 1.5, size / 2);
  c.stroke();
  return ctx.createPattern(tile, 'repeat');
}

function integerSplits(xs) {
  return () => xs;
}

function criteriaChart(container, cohort, t) {
  const s = m.criteriaSeries(cohort);
  const bars = uPlot.paths.bars({ size: [0.6, 80] });
  const safetyColour = m.PALETTE[1];
  const opts = {
    width: chartWidth(container),
    height: CHART_HEIGHT_PX + CRITERIA_AXIS_PX,
    cursor: { show: false },
    legend: { show: true, live: false },
    scales: { x: { time: false, range: [0.5, s.x.length + 0.5] }, y: { range: [0, 1] } },
    axes: [
      axis(t, { grid: { show: false }, splits: integerSplits(s.x), rotate: -35, size: CRITERIA_AXIS_PX,
        values: (u, splits) => splits.map((v) => s.labels[v - 1] || '') }),
      axis(t, { label: 'Pass rate', values: (u, splits) => splits.map((v) => v.toFixed(1)) }),
    ],
    series: [
      { label: 'Criterion' },
      { label: 'Other criteria (plain bars)', stroke: m.PALETTE[0], fill: m.PALETTE[0] + 'aa', width: 1, paths: bars, points: { show: false } },
      { label: 'Safety criteria (hatched bars)', stroke: safetyColour, fill: (u) => hatch(u.ctx, safetyColour), width: 2,
        paths: bars, points: { show: false } },
    ],
  };
  return new uPlot(opts, [s.x, s.other, s.safety], container);
}

/** Draws the pass threshold as a thin line with its value (after the series). */
function thresholdHook(threshold, t) {
  return (u) => {
    const y = u.valToPos(threshold, 'y', true);
    const { left, width } = u.bbox;
    const ctx = u.ctx;
    ctx.save();
    ctx.strokeStyle = t.muted;
    ctx.lineWidth = devicePixelRatio;
    ctx.beginPath();
    ctx.moveTo(left, y);
    ctx.lineTo(left + width, y);
    ctx.stroke();
    ctx.fillStyle = t.fg;
    ctx.font = `${12 * devicePixelRatio}px system-ui, sans-serif`;
    ctx.textAlign = 'right';
    ctx.fillText(`pass threshold ${m.fmt(threshold)}`, left + width - 4 * devicePixelRatio, y - 4 * devicePixelRatio);
    ctx.restore();
  };
}

function curvesChart(container, learners, band, threshold, t) {
  const data = m.curveSeries(learners, band);
  const xs = data[0];
  const series = [
    { label: 'Scored attempt' },
    { label: 'Lower quartile (thin line)', stroke: t.muted, width: 1, points: { show: false } },
    { label: 'Median (long dashes)', stroke: t.fg, width: 2, dash: m.MEDIAN_DASH, points: { show: false } },
    { label: 'Upper quartile (thin line)', stroke: t.muted, width: 1, points: { show: false } },
    ...learners.map((l, i) => {
      const st = m.seriesStyle(i);
      return {
        label: `${m.learnerLabel(l)} (${m.dashWords(st.dash)}, ${i % 2 ? 'hollow' : 'filled'} points)`,
        stroke: st.stroke, width: 2, dash: st.dash, spanGaps: true,
        points: { show: true, size: st.pointSize, width: 2, stroke: st.stroke, fill: i % 2 ? t.bg : st.stroke },
      };
    }),
  ];
  const opts = {
    width: chartWidth(container),
    height: CHART_HEIGHT_PX,
    legend: { show: true, live: false },
    scales: { x: { time: false, range: [0.5, Math.max(1, xs.length) + 0.5] }, y: { range: [0, 1] } },
    axes: [axis(t, { label: 'Scored attempt', splits: integerSplits(xs), values: (u, sp) => sp.map(String) }),
      axis(t, { label: 'Score', values: (u, sp) => sp.map((v) => v.toFixed(1)) })],
    series,
    bands: [{ series: [3, 1], fill: t.muted + BAND_ALPHA_HEX }],
    hooks: { draw: [thresholdHook(threshold, t)] },
  };
  return new uPlot(opts, data, container);
}

function doseChart(container, learners, t) {
  const { data, ticks } = m.doseSeries(learners);
  const point = (colour, hollow) => ({ show: true, size: DOSE_POINT_PX, width: 2, stroke: colour, fill: hollow ? t.bg : colour });
  const upFrom0 = (u, min, max) => [0, max > 0 ? max * AXIS_HEADROOM : 1];
  const opts = {
    width: chartWidth(container),
    height: CHART_HEIGHT_PX,
    legend: { show: true, live: false },
    scales: { x: { time: false, range: [0.5, Math.max(1, data[0].length) + 0.5] }, dose: { range: upFrom0 }, s: { range: upFrom0 } },
    axes: [
      axis(t, { grid: { show: false }, splits: integerSplits([...ticks.keys()]), values: (u, sp) => sp.map((v) => ticks.get(v) || '') }),
      axis(t, { scale: 'dose', label: 'mGy · Gy cm²' }),
      axis(t, { scale: 's', side: 1, label: 'Fluoroscopy time (s)', grid: { show: false } }),
    ],
    series: [
      { label: 'Attempt' },
      { label: 'Air kerma, mGy (solid)', scale: 'dose', stroke: m.PALETTE[0], width: 2, points: point(m.PALETTE[0], false) },
      { label: 'Kerma-area product, Gy cm² (dashed)', scale: 'dose', stroke: m.PALETTE[1], width: 2, dash: [10, 5],
        points: point(m.PALETTE[1], true) },
      { label: 'Fluoroscopy time, s (dotted)', scale: 's', stroke: m.PALETTE[2], width: 2, dash: [2, 4], points: point(m.PALETTE[2], false) },
    ],
  };
  return new uPlot(opts, data, container);
}

function fillTable(id, rows, cells) {
  $(id).tBodies[0].replaceChildren(...rows.map((r) => {
    const tr = el('tr');
    cells(r).forEach((c, i) => {
      const cell = i === 0 ? el('th', { scope: 'row' }) : el('td');
      if (c instanceof Node) cell.append(c); else cell.textContent = c;
      tr.append(cell);
    });
    return tr;
  }));
}

function competencyCell(w) {
  const strong = el('strong', { textContent: w.safety ? `${w.label} (${w.failed.join(', ')})` : w.label });
  const span = el('span', { className: `competency competency-${w.safety ? 'safety' : w.status.replace(/_/g, '-')}` });
  const icon = { competent: '✓', not_yet: w.safety ? '⚠' : '✗', too_few_attempts: '…' }[w.status] || '';
  if (icon) {
    const mark = el('span', { textContent: `${icon} ` });
    mark.setAttribute('aria-hidden', 'true');
    span.append(mark);
  }
  span.append(strong);
  return span;
}

function renderTables(cohort, reference) {
  const learners = cohort.learners;
  fillTable('criteria-table', m.criteriaRows(cohort), (r) => [r.id, r.description, r.kind === 'safety' ? 'safety' : 'other',
    String(r.met), String(r.not_met), String(r.missing), r.rate]);
  fillTable('curve-table', m.curveRows(learners), (r) => [r.learner, String(r.k), String(r.n), r.score]);
  fillTable('band-table', m.bandRows(reference.band), (r) => [String(r.k), String(r.learners), r.p25, r.median, r.p75]);
  fillTable('dose-table', m.doseRows(learners), (r) => [r.learner, String(r.n), r.mode, r.state, r.score, r.outcome, r.kerma, r.kap, r.time]);
  fillTable('competency-table', learners, (l) => {
    const w = m.competencyWords(l);
    return [m.learnerLabel(l), competencyCell(w), w.reason, w.judgedNumbers.length ? `attempts ${w.judgedNumbers.join(', ')}` : 'none'];
  });
  for (const tr of $('competency-table').tBodies[0].rows) {
    if (tr.querySelector('.competency-safety')) tr.classList.add('row-safety');
  }
}

function renderCharts() {
  for (const c of page.charts) c.destroy();
  page.charts = [];
  const { cohort, reference } = page;
  if (!cohort) return;
  const t = theme();
  const learners = cohort.learners;
  page.charts.push(criteriaChart($('criteria-chart'), cohort, t));
  page.charts.push(curvesChart($('curves-chart'), learners, reference.band, cohort.pass_threshold, t));
  page.charts.push(doseChart($('dose-chart'), learners, t));
  // Which theme the charts were drawn in (the browser test waits on it after a theme change).
  $('cohort-view').dataset.chartTheme = matchMedia('(prefers-color-scheme: dark)').matches ? 'dark' : 'light';
  const safety = cohort.criteria.filter((c) => c.critical).length;
  $('criteria-figure').setAttribute('aria-label', `Bar chart of the pass rate of ${cohort.criteria.length} criteria, `
    + `${safety} of them safety criteria (hatched), over ${cohort.scored_attempts} scored attempts. The table below holds the values.`);
  $('curves-figure').setAttribute('aria-label', m.curveSummary(learners, reference.band, cohort.pass_threshold));
  const attempts = learners.reduce((n, l) => n + l.attempts.length, 0);
  $('dose-figure').setAttribute('aria-label', `Chart of air kerma, kerma-area product and fluoroscopy time for ${attempts} `
    + 'attempts, learner after learner. The table below holds the values.');
}

function render() {
  const { cohort, reference } = page;
  $('cohort-title').textContent = `${cohort.station_title}: cohort`;
  $('cohort-summary').textContent = `${cohort.attempts} attempts, ${cohort.scored_attempts} scored, `
    + `${cohort.learners.length} learner${cohort.learners.length === 1 ? '' : 's'}; pass threshold ${m.fmt(cohort.pass_threshold)}.`;
  $('notice').textContent = cohort.notice;
  const learnerSel = $('learner-select');
  const chosen = learnerSel.value;
  learnerSel.replaceChildren(el('option', { value: '', textContent: 'All learners' }),
    ...reference.learners.map((l) => el('option', { value: l.learner_id, textContent: `${m.learnerLabel(l)} (${l.email})` })));
  if (chosen && !reference.learners.some((l) => l.learner_id === chosen)) {
    learnerSel.append(el('option', { value: chosen, textContent: 'The chosen learner (no attempts here)' }));
  }
  learnerSel.value = chosen;
  renderTables(cohort, reference);
  $('cohort-view').hidden = false;
  renderCharts();
}

function filters() {
  return { course: $('course-select').value, station: $('station-select').value, learner: $('learner-select').value, mode: $('mode-select').value };
}

async function load() {
  const f = filters();
  if (!f.course || !f.station) return;
  const seq = ++page.loadSeq;
  history.replaceState(null, '', `${location.pathname}${m.pageSearch(f)}`);
  $('csv-link').href = m.csvUrl(f.course, f);
  status('Loading…');
  try {
    // The whole cohort (in the chosen mode) gives the reference band and the learner list; a
    // learner filter narrows the rest. The server computes a filtered answer's band from that
    // learner's own scores, which is no reference.
    const reference = await api('GET', m.cohortUrl(f.course, { ...f, learner: '' }));
    const cohort = f.learner ? await api('GET', m.cohortUrl(f.course, f)) : reference;
    if (seq !== page.loadSeq) return;
    Object.assign(page, { cohort, reference });
    // Clear an earlier load's error, and only that (a warning from the start stays).
    if (page.loadFailed) say('');
    page.loadFailed = false;
    render();
    status(cohort.attempts === 0 ? 'No attempts match these filters.'
      : `Showing ${cohort.attempts} attempts of ${cohort.learners.length} learner${cohort.learners.length === 1 ? '' : 's'}.`);
  } catch (e) {
    if (seq !== page.loadSeq) return;
    $('cohort-view').hidden = true;
    status('');
    page.loadFailed = true;
    if (e instanceof ApiError && e.status === 403) say('The cohort dashboard is for faculty of this course (or an admin).');
    else if (e instanceof ApiError && e.status === 404) say('No such course or station for you.');
    else say(`The cohort could not be loaded: ${e.message}`);
  }
}

// ---------------------------------------------------------------- station modes

function modeSelect(setting, title) {
  const sel = el('select', { name: `mode-${setting.station_id}` });
  sel.setAttribute('aria-label', `Mode of ${title}`);
  sel.append(el('option', { value: 'practice', textContent: 'Practice (hints allowed)' }),
    el('option', { value: 'assessment', textContent: 'Assessment (no hints)' }));
  sel.value = setting.mode;
  return sel;
}

function lastSet(setting) {
  if (!setting.set_at) return 'never (practice by default)';
  const who = setting.set_by && page.me && setting.set_by === page.me.user.id ? 'you' : 'faculty';
  return `${new Date(setting.set_at).toLocaleString()} by ${who}`;
}

async function loadModes(course) {
  const modesSay = (t) => { $('modes-status').textContent = t; };
  try {
    const modes = await api('GET', `/api/courses/${encodeURIComponent(course)}/station-modes`);
    const title = (id) => (page.stations.find((s) => s.id === id) || { title: id }).title;
    $('modes-table').tBodies[0].replaceChildren(...modes.map((s) => {
      const sel = modeSelect(s, title(s.station_id));
      const when = el('td', { textContent: lastSet(s) });
      const save = el('button', { type: 'button', textContent: 'Save' });
      save.setAttribute('aria-label', `Save the mode of ${title(s.station_id)}`);
      save.dataset.station = s.station_id;
      save.addEventListener('click', async () => {
        save.disabled = true;
        try {
          const r = await api('PUT', `/api/courses/${encodeURIComponent(course)}/station-modes/${encodeURIComponent(s.station_id)}`, { mode: sel.value });
          when.textContent = lastSet(r);
          modesSay(`Saved: ${title(s.station_id)} now runs in ${r.mode} mode in this course.`);
        } catch (e) {
          modesSay(`Not saved: ${e.message}`);
        } finally {
          save.disabled = false;
        }
      });
      return el('tr', {}, el('th', { scope: 'row', textContent: title(s.station_id) }), el('td', {}, sel), when, el('td', {}, save));
    }));
    $('modes-section').hidden = false;
  } catch (e) {
    $('modes-section').hidden = true;
    say(`The station modes could not be loaded: ${e.message}`);
  }
}

// ---------------------------------------------------------------- start

function fillSelect(sel, items, value) {
  sel.replaceChildren(...items.map(([v, text]) => el('option', { value: v, textContent: text })));
  if (items.some(([v]) => v === value)) sel.value = value;
}

async function start() {
  if (typeof uPlot !== 'function') {
    say('The chart library did not load (vendor/uplot/uPlot.iife.min.js).');
    return;
  }
  let me;
  try {
    me = await api('GET', '/api/auth/me');
  } catch (e) {
    say('Log in on the simulator\'s home page first (the link above), then come back to this page.');
    return;
  }
  page.me = me;
  setCsrf(me.csrf_token);
  $('who').textContent = `${me.user.display_name} (${me.user.role})`;
  if (me.user.role === 'learner') {
    say('The cohort dashboard is for faculty: it shows every learner\'s results. Your own attempts are on the simulator\'s home page.');
    return;
  }
  const params = m.pageParams(location.search);
  try {
    [page.courses, page.stations] = await Promise.all([api('GET', '/api/courses'), api('GET', '/api/stations')]);
  } catch (e) {
    say(`The courses could not be loaded: ${e.message}`);
    return;
  }
  const mine = me.user.role === 'admin' ? page.courses : page.courses.filter((c) => c.my_role === 'faculty');
  if (!mine.length) {
    say('The cohort dashboard is for faculty of a course, and you are faculty of none.');
    return;
  }
  if (params.course && !mine.some((c) => c.id === params.course)) {
    say('That course is not one of yours: the cohort dashboard is for faculty of the course. Showing your first course.');
  }
  fillSelect($('course-select'), mine.map((c) => [c.id, `${c.code} — ${c.title}`]), params.course);
  fillSelect($('station-select'), page.stations.map((s) => [s.id, s.title]), params.station);
  if (params.learner) $('learner-select').append(el('option', { value: params.learner, textContent: 'The learner named in the address' }));
  $('learner-select').value = params.learner;
  $('mode-select').value = params.mode;
  $('picker').hidden = false;
  $('course-select').addEventListener('change', () => {
    $('learner-select').value = '';
    load();
    loadModes($('course-select').value);
  });
  $('station-select').addEventListener('change', load);
  $('learner-select').addEventListener('change', load);
  $('mode-select').addEventListener('change', load);
  $('filters').addEventListener('submit', (ev) => ev.preventDefault());
  let resizeTimer = null;
  window.addEventListener('resize', () => {
    clearTimeout(resizeTimer);
    resizeTimer = setTimeout(() => {
      for (const c of page.charts) c.setSize({ width: chartWidth(c.root.parentElement), height: c.height });
    }, RESIZE_DEBOUNCE_MS);
  });
  matchMedia('(prefers-color-scheme: dark)').addEventListener('change', renderCharts);
  await Promise.all([load(), loadModes($('course-select').value)]);
}

start();
