// The fluoroscopy viewer's display state and its arithmetic, as in OHIF / Cornerstone: window and
// level applied as a grey-level look-up table, zoom, pan, invert and flips, and the mapping
// between image pixels and canvas pixels (both ways). Pure functions: nothing here touches the
// DOM, so node's test runner loads this module (web-client/tests/unit/viewer.test.mjs).
//
// Coordinates: an image pixel position `[x, y]` is continuous (the image's top-left corner is
// [0, 0], x to the right, y down), as in sim-core's fluoro geometry; a canvas position is in the
// canvas's own pixels (its `width` x `height`, not its CSS size).

/** Default window width and level: the full 8-bit range mapped onto itself (255 wide, centred on
 * 127.5), so the default view draws the decoded frame unchanged. Source: the frames are 8-bit
 * JPEG grey levels (render_worker::session::frame). */
export const DEFAULT_WINDOW = 255;
export const DEFAULT_LEVEL = 127.5;
/** Narrowest window, grey levels (simulator choice: one level is a hard threshold). */
export const MIN_WINDOW = 1;
/** Widest window, grey levels (simulator choice: four times the 8-bit range is a washed-out
 * image, enough to undo any contrast). */
export const MAX_WINDOW = 1020;
/** Window/level change per screen pixel of a drag, grey levels (Cornerstone's WWWC tool moves
 * one level a pixel at its default sensitivity). */
export const WL_PER_PX = 1;
/** Zoom limits (simulator choice: a quarter to 8 times the fitted image; 8 x shows a 512-pixel
 * frame's pixels as 8 x 8 blocks on a 512-pixel canvas). */
export const MIN_ZOOM = 0.25;
export const MAX_ZOOM = 8;
/** Zoom factor per `+` / `-` key press (simulator choice: three presses about double it,
 * 1.25^3 = 1.95). */
export const ZOOM_STEP = 1.25;
/** Right-drag zoom: the zoom is multiplied by e for this many screen pixels of upward drag
 * (simulator choice: a 140 px drag doubles it). */
export const ZOOM_DRAG_PX = 200;

/** The view a session starts with and `space` returns to. */
export function defaultView() {
  return { zoom: 1, pan: [0, 0], flipH: false, flipV: false, invert: false, window: DEFAULT_WINDOW, level: DEFAULT_LEVEL };
}

const clamp = (v, lo, hi) => Math.max(lo, Math.min(hi, v));

/** The affine map image pixel -> canvas pixel of `view` for an image of `image` = [w, h] pixels
 * shown fitted on a canvas of `canvas` = [w, h] pixels: `{ a, d, e, f }` with
 * canvas = [a x + e, d y + f] (no rotation or shear, so b = c = 0 in canvas terms). The image
 * centre lands at the canvas centre plus the pan; flips mirror about the image centre. */
export function transform(view, image, canvas) {
  const fit = Math.min(canvas[0] / image[0], canvas[1] / image[1]);
  const a = fit * view.zoom * (view.flipH ? -1 : 1);
  const d = fit * view.zoom * (view.flipV ? -1 : 1);
  return {
    a, d,
    e: canvas[0] / 2 + view.pan[0] - a * (image[0] / 2),
    f: canvas[1] / 2 + view.pan[1] - d * (image[1] / 2),
  };
}

/** Canvas position of image pixel position `p`. */
export function imageToCanvas(view, image, canvas, p) {
  const t = transform(view, image, canvas);
  return [t.a * p[0] + t.e, t.d * p[1] + t.f];
}

/** Image pixel position under canvas position `c` (the inverse of `imageToCanvas`). */
export function canvasToImage(view, image, canvas, c) {
  const t = transform(view, image, canvas);
  return [(c[0] - t.e) / t.a, (c[1] - t.f) / t.d];
}

/** A screen direction (`dx` to the right, `dy` up, any unit) in the image's own axes: the flips
 * undone (a flipped image's screen-right is the image's left). */
export function screenToImageDirection(view, dx, dy) {
  return [view.flipH ? -dx : dx, view.flipV ? -dy : dy];
}

/** The grey-level look-up table of a window (width) and level (centre), inverted on request:
 * 256 output levels for the 256 input ones. Levels below the window are black, above it white,
 * linear between (Cornerstone's linear VOI LUT). */
export function lut(window, level, invert) {
  const out = new Uint8ClampedArray(256);
  const w = Math.max(MIN_WINDOW, window);
  const lower = level - w / 2;
  for (let v = 0; v < 256; v++) {
    const g = Math.round(clamp((255 * (v - lower)) / w, 0, 255));
    out[v] = invert ? 255 - g : g;
  }
  return out;
}

/** Whether `view`'s look-up table leaves every grey level as it is (the frame can be drawn
 * without touching its pixels). */
export function isIdentityLut(view) {
  return !view.invert && view.window === DEFAULT_WINDOW && view.level === DEFAULT_LEVEL;
}

/** Applies `table` to the RGBA pixels `data` (an ImageData's data) in place; alpha is kept. */
export function applyLut(data, table) {
  for (let i = 0; i < data.length; i += 4) {
    data[i] = table[data[i]];
    data[i + 1] = table[data[i + 1]];
    data[i + 2] = table[data[i + 2]];
  }
  return data;
}

/** Window/level after a left drag of (`dx`, `dy`) screen pixels from `start` (right widens the
 * window, down raises the level, so the image darkens: Cornerstone's convention). */
export function windowLevelDrag(start, dx, dy) {
  return {
    ...start,
    window: clamp(Math.round(start.window + dx * WL_PER_PX), MIN_WINDOW, MAX_WINDOW),
    level: start.level + dy * WL_PER_PX,
  };
}

/** `view` zoomed by `factor` about the canvas centre (the pan scales with it, so the image
 * point at the centre stays there), within MIN_ZOOM..MAX_ZOOM. */
export function zoomBy(view, factor) {
  const zoom = clamp(view.zoom * factor, MIN_ZOOM, MAX_ZOOM);
  const k = zoom / view.zoom;
  return { ...view, zoom, pan: [view.pan[0] * k, view.pan[1] * k] };
}

/** Zoom after a right drag of `dy` screen pixels (up, negative dy, zooms in) from `start`. */
export function zoomDrag(start, dy) {
  return zoomBy(start, Math.exp(-dy / ZOOM_DRAG_PX));
}

/** `view` panned by (`dx`, `dy`) canvas pixels. */
export function panBy(view, dx, dy) {
  return { ...view, pan: [view.pan[0] + dx, view.pan[1] + dy] };
}
