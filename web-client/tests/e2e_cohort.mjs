// The faculty cohort dashboard (cohort.html) in headless Chromium, against a server whose demo
// course already holds scored attempts at the demo station (set up by
// server/tests/e2e_cohort.rs): the charts are drawn, the data tables hold the right rows, the
// competency words are right, the CSV link downloads one row per attempt, the learner filter
// narrows the tables, a station mode set to assessment survives a reload, the page passes
// axe-core's WCAG 2.0 and 2.1 A/AA rules, and a learner is told the page is for faculty.
//
// Usage: node tests/e2e_cohort.mjs http://127.0.0.1:PORT/ [screenshot-dir]
// Environment: E2E_COURSE (the demo course's id), E2E_STATION (the station), E2E_LEARNER2
// (the e-mail of the learner to filter by).

import { mkdirSync, readFileSync } from 'node:fs';
import { join } from 'node:path';
import { axeViolations, login, runReport, waitUntil } from './harness.mjs';

const base = process.argv[2] || 'http://127.0.0.1:8080/';
const shots = process.argv[3] || null;
const course = process.env.E2E_COURSE;
const station = process.env.E2E_STATION || 'demo-station';
const learner2 = process.env.E2E_LEARNER2 || 'learner2@demo.invalid';

/** What the page shows: chart canvases (size and painted pixels), table rows, figure wiring. */
function pageState() {
  const rows = (id) => [...document.getElementById(id).tBodies[0].rows]
    .map((tr) => [...tr.cells].map((c) => c.textContent.trim()));
  const chart = (id) => {
    const canvas = document.querySelector(`#${id} canvas`);
    if (!canvas) return null;
    const ctx = canvas.getContext('2d');
    const px = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
    let painted = 0;
    const colours = new Set();
    for (let i = 3; i < px.length; i += 4) {
      if (px[i] > 0) {
        painted += 1;
        colours.add((px[i - 3] << 16) | (px[i - 2] << 8) | px[i - 1]);
      }
    }
    return { width: canvas.width, height: canvas.height, painted, colours: colours.size };
  };
  const figure = (id) => {
    const f = document.getElementById(id);
    const next = f.nextElementSibling;
    return { role: f.getAttribute('role'), label: f.getAttribute('aria-label') || '',
      caption: (f.querySelector('figcaption') || { textContent: '' }).textContent.trim(),
      followed_by_table: !!next && next.tagName === 'TABLE' && !!next.caption };
  };
  const unnamed = [...document.querySelectorAll('select, button, input, a[href]')]
    .filter((e) => e.offsetParent !== null)
    .filter((e) => !(e.getAttribute('aria-label') || (e.labels && e.labels.length) || e.textContent.trim()))
    .map((e) => e.outerHTML.slice(0, 80));
  return {
    charts: { criteria: chart('criteria-chart'), curves: chart('curves-chart'), dose: chart('dose-chart') },
    figures: { criteria: figure('criteria-figure'), curves: figure('curves-figure'), dose: figure('dose-figure') },
    criteria: rows('criteria-table'), curves: rows('curve-table'), band: rows('band-table'),
    dose: rows('dose-table'), competency: rows('competency-table'),
    safety_rows: document.querySelectorAll('#competency-table tr.row-safety').length,
    csv_href: document.getElementById('csv-link').getAttribute('href'),
    learner_options: [...document.getElementById('learner-select').options].map((o) => o.textContent),
    notice: document.getElementById('notice').textContent,
    address: location.search,
    unnamed_controls: unnamed,
  };
}

async function shot(page, name) {
  if (!shots) return;
  mkdirSync(shots, { recursive: true });
  await page.screenshot({ path: join(shots, `${name}.png`), fullPage: true });
}

async function dashboardReady(page, learners) {
  await waitUntil(page, (n) => {
    const view = document.getElementById('cohort-view');
    const t = document.getElementById('competency-table');
    return view && !view.hidden && t.tBodies[0].rows.length === n && document.getElementById('status').textContent.startsWith('Showing');
  }, learners);
}

await runReport(async (page, report) => {
  if (!course) throw new Error('E2E_COURSE is not set');
  const dashboard = `${base}cohort.html?course=${course}&station=${encodeURIComponent(station)}`;

  // Faculty log in on the simulator's page, then open the dashboard as the faculty screen links it.
  await page.goto(base);
  await page.waitForSelector('#login-view:not([hidden])');
  await login(page, 'faculty@demo.invalid');
  await page.waitForSelector('#faculty-view:not([hidden])');
  await page.goto(dashboard);
  await dashboardReady(page, 2);
  report.all = await page.evaluate(pageState);
  report.steps.push('dashboard');
  await shot(page, 'cohort-all');

  // The CSV link downloads the same attempts: one header row and one row per attempt.
  const [download] = await Promise.all([page.waitForEvent('download'), page.click('#csv-link')]);
  const csv = readFileSync(await download.path(), 'utf8');
  const lines = csv.split('\r\n').filter((l) => l.length > 0);
  const header = lines[0].split(',').map((h) => h.replace(/^"(.*)"$/, '$1'));
  report.csv = { file: download.suggestedFilename(), header, rows: lines.length - 1 };
  report.steps.push('csv');

  // The learner filter narrows the tables and the CSV link; the band stays the cohort's.
  const value = await page.evaluate((email) => [...document.getElementById('learner-select').options]
    .find((o) => o.textContent.includes(email)).value, learner2);
  await page.selectOption('#learner-select', value);
  await dashboardReady(page, 1);
  report.filtered = await page.evaluate(pageState);
  report.filtered.learner_id = value;
  const [download2] = await Promise.all([page.waitForEvent('download'), page.click('#csv-link')]);
  report.filtered.csv_rows = readFileSync(await download2.path(), 'utf8').split('\r\n').filter((l) => l.length > 0).length - 1;
  report.steps.push('filtered');
  await shot(page, 'cohort-filtered');

  // The mode filter: every attempt here ran in practice, so assessment only shows none, without
  // a script error; then back to both modes.
  await page.selectOption('#mode-select', 'assessment');
  await waitUntil(page, () => document.getElementById('status').textContent.startsWith('No attempts'));
  report.assessment_only = await page.evaluate(() => ({
    status: document.getElementById('status').textContent,
    dose_rows: document.getElementById('dose-table').tBodies[0].rows.length,
    csv_href: document.getElementById('csv-link').getAttribute('href'),
    canvases: document.querySelectorAll('#cohort-view canvas').length,
  }));
  await page.selectOption('#mode-select', '');
  await dashboardReady(page, 1);
  report.steps.push('mode filter');

  // The dark theme redraws the charts in its colours.
  await page.emulateMedia({ colorScheme: 'dark' });
  await waitUntil(page, () => document.getElementById('cohort-view').dataset.chartTheme === 'dark');
  report.dark = await page.evaluate(pageState);
  report.dark.theme = await page.evaluate(() => document.getElementById('cohort-view').dataset.chartTheme);
  report.steps.push('dark');
  await shot(page, 'cohort-dark');
  await page.emulateMedia({ colorScheme: 'light' });

  // axe-core's WCAG 2.0 and 2.1 A and AA rules over the whole page. Evaluated through the DevTools
  // protocol, which the page's Content-Security-Policy does not govern.
  report.axe = await axeViolations(page);
  report.steps.push('axe');

  // The station's mode set to assessment, saved, and still so after a reload.
  const select = `#modes-table select[name="mode-${station}"]`;
  await page.waitForSelector(select);
  report.mode_before = await page.inputValue(select);
  await page.selectOption(select, 'assessment');
  await page.click(`#modes-table button[data-station="${station}"]`);
  await waitUntil(page, () => document.getElementById('modes-status').textContent.length > 0);
  report.mode_saved_text = await page.textContent('#modes-status');
  await page.reload();
  await dashboardReady(page, 1);
  await page.waitForSelector(select);
  report.mode_after_reload = await page.inputValue(select);
  report.address_after_reload = await page.evaluate(() => location.search);
  report.steps.push('mode');

  // A learner gets the "for faculty" message, and no cohort.
  await page.goto(base);
  await page.waitForSelector('#faculty-view:not([hidden])');
  await page.click('#logout');
  await page.waitForSelector('#login-view:not([hidden])');
  await login(page, 'learner@demo.invalid');
  await page.waitForSelector('#learner-view:not([hidden])');
  await page.goto(dashboard);
  await waitUntil(page, () => document.getElementById('message').textContent.length > 0);
  report.learner_message = await page.textContent('#message');
  report.learner_sees_cohort = await page.evaluate(() => !document.getElementById('cohort-view').hidden
    || !document.getElementById('picker').hidden);
  report.steps.push('learner');
  await shot(page, 'cohort-learner');
});
