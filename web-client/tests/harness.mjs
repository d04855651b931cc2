// What the browser end-to-end scripts share: headless Chromium (Debian's /usr/bin/chromium,
// driven by playwright-core) with console errors collected, waiting on page state under the
// server's Content-Security-Policy, and logging in and opening the first station as the demo
// learner.

import { chromium } from 'playwright-core';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { createRequire } from 'node:module';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

export const DEMO_PASSWORD = process.env.E2E_PASSWORD || 'demo-password-not-secret';
export const STEP_TIMEOUT_MS = 60_000;

// Polls `predicate(arg)` in the page until it is true. Not page.waitForFunction: that compiles
// its predicate inside the page, which the server's Content-Security-Policy (no 'unsafe-eval')
// rightly refuses; page.evaluate goes through the DevTools protocol instead.
export async function waitUntil(page, predicate, arg = null, options = {}) {
  const timeout = options.timeout ?? STEP_TIMEOUT_MS;
  const deadline = Date.now() + timeout;
  for (;;) {
    if (await page.evaluate(predicate, arg)) return;
    if (Date.now() > deadline) throw new Error(`timed out after ${timeout} ms waiting for ${predicate}`);
    await new Promise((r) => setTimeout(r, 25));
  }
}

export async function login(page, email, code) {
  await page.fill('#login-email', email);
  await page.fill('#login-password', DEMO_PASSWORD);
  if (code) await page.fill('#login-totp', code);
  await page.click('#login-submit');
}

/** HTTP error answers the client meets by design, by path: the session probe before login is
 * refused with 401 (no session yet), and health answers 503 while the render worker's GPU check
 * runs. Any other error answer, every other 5xx included, is a console error of the run. */
const EXPECTED_HTTP_ERRORS = [
  { path: '/api/auth/me', status: 401 },
  { path: '/healthz', status: 503 },
];

function isExpectedHttpError(url, status) {
  let path;
  try { path = new URL(url).pathname; } catch { return false; }
  return EXPECTED_HTTP_ERRORS.some((e) => (e.pattern ? e.pattern.test(path) : e.path === path) && e.status === status);
}

/** Adds an error answer that a script provokes on purpose (for example the 503 of a session
 * request while the anatomy is prepared): paths matching `pattern` with `status` are then not
 * console errors of the run. */
export function expectHttpError(pattern, status) {
  EXPECTED_HTTP_ERRORS.push({ pattern, status });
}

/** Starts Chromium with a fresh profile in `profile`; collects script errors. */
export async function launch(profile) {
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync'],
    viewport: { width: 1200, height: 900 },
  });
  const page = context.pages()[0] || await context.newPage();
  const consoleErrors = [];
  // Script errors, and the browser's own "Failed to load resource" line for every HTTP error
  // answer except those the client meets by design (EXPECTED_HTTP_ERRORS): an API 500, or any
  // other refusal the client did not ask for, fails the run even when the page carries on.
  page.on('console', (m) => {
    if (m.type() !== 'error') return;
    const text = m.text();
    const failed = /^Failed to load resource: the server responded with a status of (\d+)/.exec(text);
    const url = m.location().url || '';
    if (failed && isExpectedHttpError(url, Number(failed[1]))) return;
    consoleErrors.push(url ? `${text} (${url})` : text);
  });
  page.on('pageerror', (e) => consoleErrors.push(String(e)));
  page.setDefaultTimeout(STEP_TIMEOUT_MS);
  return { context, page, consoleErrors };
}

/** Logs in as the demo learner at `base`, starts an attempt at the first station and waits for
 * the live session; returns the station id. */
export async function openFirstStation(page, base) {
  await page.goto(base);
  await page.waitForSelector('#login-view:not([hidden])');
  await login(page, 'learner@demo.invalid');
  await page.waitForSelector('#learner-view:not([hidden])');
  const stationButton = page.locator('#station-list button').first();
  const station = await stationButton.getAttribute('data-station');
  await stationButton.click();
  await page.waitForSelector('#session-view:not([hidden])');
  await waitUntil(page, () => document.getElementById('conn').textContent === 'live');
  return station;
}

/** Runs `steps(page, report)` in a fresh browser profile and prints the report as one JSON line
 * (`ok` when every step passed, else `error`, and the console errors); exits 0 or 1. */
export async function runReport(steps) {
  const profile = mkdtempSync(join(tmpdir(), 'painsim-e2e-chromium-'));
  const report = { ok: false, steps: [] };
  let context;
  try {
    let page, consoleErrors;
    ({ context, page, consoleErrors } = await launch(profile));
    await steps(page, report);
    report.console_errors = consoleErrors;
    report.ok = true;
  } catch (e) {
    report.error = String(e && e.stack ? e.stack : e);
  } finally {
    if (context) await context.close().catch(() => {});
    rmSync(profile, { recursive: true, force: true });
  }
  console.log(JSON.stringify(report));
  process.exit(report.ok ? 0 : 1);
}

/** The rule sets of the accessibility checks: WCAG 2.0 and 2.1, levels A and AA. */
export const WCAG_21_AA = ['wcag2a', 'wcag2aa', 'wcag21a', 'wcag21aa'];

/** axe-core's violations of `tags` on the page as it is now. axe-core (web-client/node_modules)
 * is injected through the DevTools protocol, which the page's Content-Security-Policy does not
 * govern, so the policy stays as the server sends it. */
export async function axeViolations(page, tags = WCAG_21_AA) {
  const require = createRequire(import.meta.url);
  await page.evaluate(readFileSync(require.resolve('axe-core/axe.min.js'), 'utf8'));
  return page.evaluate(async (t) => {
    const r = await window.axe.run(document, { runOnly: { type: 'tag', values: t }, resultTypes: ['violations'] });
    return r.violations.map((v) => ({
      id: v.id,
      impact: v.impact,
      help: v.help,
      nodes: v.nodes.slice(0, 6).map((n) => ({ target: n.target.join(' '), summary: n.failureSummary })),
    }));
  }, tags);
}
