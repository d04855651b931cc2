// What the debrief page shows, in words and rectangles: measured values in their units, a
// station's tolerance in words, the technical outcome, and the reveal's outline runs as the
// rectangles to draw with one colour per structure. Pure: no DOM.

/** Outline colours of the touched structures, in the order the needle entered them. Source: the
 * Okabe-Ito colour-blind-safe palette (Okabe & Ito 2008, "Color Universal Design") without its
 * black (invisible on bone-dark parts of a radiograph), saturated so that no grey pixel of the
 * image underneath can have one of these colours; beyond seven the palette repeats, and the
 * legend's order still tells the structures apart. */
export const OUTLINE_COLOURS = ['#e69f00', '#56b4e9', '#009e73', '#f0e442', '#0072b2', '#d55e00', '#cc79a7'];

/** Pixels added on each side of an outline pixel when drawn. Simulator choice: the reveal's
 * outlines are one image pixel wide, which at the 512 px the image is shown at is too thin to
 * see against the grain of a fluoroscopy image; 1 px more on each side makes a 3 px line. */
export const OUTLINE_GROW_PX = 1;

/** A measured value in its unit, as a person reads it; the same rounding as the server's
 * explanation (`server::dispatch::debrief::shown`), so the table and the explanation agree. */
export function showValue(value, unit) {
  if (value === null || value === undefined || !Number.isFinite(Number(value))) return 'not measured';
  const v = Number(value);
  switch (unit) {
    case 'bool': return v >= 0.5 ? 'yes' : 'no';
    case 'count': return v.toFixed(0);
    case 'fraction': return `${(v * 100).toFixed(0)} %`;
    case 'mm': return `${v.toFixed(1)} mm`;
    case 'deg': return `${v.toFixed(1)}°`;
    case 's': return `${v.toFixed(1)} s`;
    case 'mgy': return `${v.toFixed(2)} mGy`;
    case 'gycm2': return `${v.toFixed(3)} Gy·cm²`;
    default: return `${v} ${unit || ''}`.trim();
  }
}

/** A station's tolerance (`{law, ...bounds}`) in words, for a value in `unit`. */
export function toleranceWords(tol, unit) {
  if (!tol || typeof tol !== 'object') return 'no tolerance stated';
  const v = (x) => showValue(x, unit);
  switch (tol.law) {
    case 'lower_is_better':
      return `full credit at or below ${v(tol.pass_within)}; none from ${v(tol.fail_beyond)}`;
    case 'near_value':
      return `ideal ${v(tol.value)}; full credit within ${v(tol.pass_within)} of it, none from ${v(tol.fail_beyond)} away`;
    case 'higher_is_better':
      return `full credit from ${v(tol.pass_from)}; none at or below ${v(tol.fail_below)}`;
    case 'boolean':
      return `expected: ${tol.expected ? 'yes' : 'no'}`;
    default:
      return `law ${tol.law}`;
  }
}

/** A criterion's status in words. */
export function statusWords(status) {
  return { met: 'Met', not_met: 'Not met', missing: 'Not measured' }[status] || String(status);
}

/** The technical outcome in neutral words. */
export function outcomeWords(outcome) {
  return { met: 'Met', not_met: 'Not met', incomplete: 'Incomplete' }[outcome] || 'No result';
}

/** A score (0..=1) as a percentage. */
export function scoreWords(score) {
  return Number.isFinite(score) ? `${(score * 100).toFixed(0)} %` : 'no score';
}

/** A structure id (`dural_sac`, `L4-vertebra`) as words (`dural sac`, `L4 vertebra`). */
export function structureWords(id) {
  return String(id).replace(/[_-]+/g, ' ').trim();
}

/** The safety (critical) criteria that failed: measured and not met. One never measured is
 * missing (the outcome is then incomplete), not failed. */
export function failedSafety(criteria) {
  return criteria.filter((c) => c.critical && c.status === 'not_met');
}

/** The colour of each touched structure, in the order the needle entered them. */
export function structureColours(touched) {
  const out = new Map();
  for (const s of touched) {
    if (!out.has(s)) out.set(s, OUTLINE_COLOURS[out.size % OUTLINE_COLOURS.length]);
  }
  return out;
}

/** `#rrggbb` as `[r, g, b]`. */
export function rgb(hex) {
  const n = parseInt(hex.slice(1), 16);
  return [(n >> 16) & 255, (n >> 8) & 255, n & 255];
}

/**
 * The rectangles that draw an outline's runs (`[row, first column, last column]` of image
 * pixels) on a canvas `scale` canvas pixels per image pixel, each grown by `grow` canvas
 * pixels on every side: `{x, y, w, h}` in whole canvas pixels (so fills stay crisp and exact).
 * Runs with a last column before the first are skipped.
 */
export function outlineRects(runs, scale = 1, grow = 0) {
  const out = [];
  for (const run of runs) {
    const [row, x0, x1] = run;
    if (!(x1 >= x0) || row < 0) continue;
    const x = Math.floor(x0 * scale) - grow;
    const y = Math.floor(row * scale) - grow;
    const w = Math.max(1, Math.ceil((x1 + 1) * scale) - Math.floor(x0 * scale)) + 2 * grow;
    const h = Math.max(1, Math.ceil((row + 1) * scale) - Math.floor(row * scale)) + 2 * grow;
    out.push({ x, y, w, h });
  }
  return out;
}

/** What to draw for a reveal: per outlined structure (in the order the needle entered them,
 * then any other outlined structure) its colour and rectangles on a canvas of `canvasWidth`
 * pixels for an image `imageWidth` wide; and the touched structures without an outline. */
export function revealDrawing(reveal, canvasWidth, grow = OUTLINE_GROW_PX) {
  const scale = canvasWidth / reveal.width;
  const order = [...reveal.touched, ...reveal.outlines.map((o) => o.structure)];
  const colours = structureColours(order);
  const byName = new Map(reveal.outlines.map((o) => [o.structure, o]));
  const layers = [...colours.keys()].filter((s) => byName.has(s)).map((s) => ({
    structure: s,
    colour: colours.get(s),
    rects: outlineRects(byName.get(s).runs, scale, grow),
  }));
  const unoutlined = reveal.touched.filter((s) => !byName.has(s));
  return { layers, colours, unoutlined };
}
