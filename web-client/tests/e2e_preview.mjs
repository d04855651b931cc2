// Progressive frames in headless Chromium: after a C-arm move and a shot on a worker that drafts,
// the page draws the draft with its "Preview" badge, then the full frame without it.
//
// Usage: node tests/e2e_preview.mjs <base-url> [out-dir]
// Prints one JSON object: `drafts` and `frames` (the session's counts), `badge` (each change of
// the badge's visibility, in order), and `final` (the last frame drawn: draft or not, and
// whether the badge is hidden).

import { waitUntil, openFirstStation, runReport } from './harness.mjs';

const base = process.argv[2];
if (!base) {
  console.error('usage: node tests/e2e_preview.mjs <base-url> [out-dir]');
  process.exit(2);
}

runReport(async (page, report) => {
  report.station = await openFirstStation(page, base);
  report.steps.push('session open');
  // Every change of the badge's visibility, recorded as it happens (a draft shows for tens of
  // milliseconds only).
  await page.evaluate(() => {
    window.__badge = [];
    const el = document.getElementById('fluoro-draft');
    new MutationObserver(() => window.__badge.push(el.hidden ? 'hidden' : 'shown'))
      .observe(el, { attributes: true, attributeFilter: ['hidden'] });
  });
  await page.focus('#fluoro');
  for (let k = 0; k < 3; k++) {
    // A C-arm turn by key (Ctrl + arrow, sent within 50 ms), then a shot by key (X) within the
    // pause after which the session would prepare the new view (150 ms: a shot after that
    // finds it prepared and comes as a full frame without a draft).
    await page.keyboard.press('Control+ArrowRight');
    await page.waitForTimeout(60);
    const before = await page.evaluate(() => window.__sim.stats.frames);
    await page.keyboard.press('x');
    // Until the full frame of the shot is drawn.
    await waitUntil(page, (n) => {
      const s = window.__sim.stats;
      return s.frames > n && s.lastFrame && s.lastFrame.draft === false
        && Number(document.getElementById('frame-count').textContent) === s.frames;
    }, before);
  }
  report.steps.push('shots');
  Object.assign(report, await page.evaluate(() => ({
    drafts: window.__sim.stats.drafts,
    frames: window.__sim.stats.frames,
    badge: window.__badge,
    final: {
      draft: window.__sim.stats.lastFrame.draft,
      badge_hidden: document.getElementById('fluoro-draft').hidden,
    },
  })));
});
