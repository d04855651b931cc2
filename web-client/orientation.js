// What the fluoroscopy overlays say, computed from the C-arm pose of the displayed image: the
// patient directions at the image's edges, the view's name, the millimetre scale at the
// isocentre, and the patient direction of a screen direction (hub tilts follow the screen).
// Pure functions (no DOM), tested by web-client/tests/unit/orientation.test.mjs.
//
// Geometry (sim-core/src/fluoro/geometry.rs, module doc): model frame x = patient right,
// y = anterior, z = cranial. The unit vector isocentre -> detector is
// n = (-sin(o) cos(a), cos(o) cos(a), sin(a)) for orbital angle o (> 0: LAO) and angular angle a
// (> 0: cranial). Screen-right is u = (-cos(o), -sin(o), 0); screen-up is
// cos(a) z - sin(a) n_o with n_o = (-sin(o), cos(o), 0). In AP the patient's right is on the
// screen's left.

/** Source to isocentre and source to detector, mm (sim_core::fluoro::geometry
 * SOURCE_TO_ISOCENTRE_MM = 730 and 730 + ISOCENTRE_TO_DETECTOR_MM = 1480); used when the
 * session's hello does not list them. */
export const SOURCE_TO_ISOCENTRE_MM = 730;
export const SOURCE_TO_DETECTOR_MM = 1480;
/** A direction's component below this is left out of its letters: sin(22.5 degrees), so a
 * letter names a direction within 67.5 degrees of it (the DICOM viewers' usual cut). */
export const LETTER_MIN_WEIGHT = 0.38;
/** Scale bar lengths offered, mm (simulator choice: 1-2-5 steps). */
export const SCALE_STEPS_MM = [1, 2, 5, 10, 20, 50, 100, 200];
/** Longest scale bar, as a fraction of the canvas width (simulator choice: it must not cover
 * the image). */
export const SCALE_MAX_FRACTION = 0.4;

const rad = (deg) => (deg * Math.PI) / 180;

/** Screen-right and screen-up of a pose as patient-frame unit vectors. */
export function screenAxes(pose) {
  const o = rad(pose.orbital);
  const a = rad(pose.angular);
  const u = [-Math.cos(o), -Math.sin(o), 0];
  const nO = [-Math.sin(o), Math.cos(o), 0];
  const up = [-Math.sin(a) * nO[0], -Math.sin(a) * nO[1], Math.cos(a)];
  return { right: u, up };
}

/** The letters of a patient-frame direction: R/L, A/P, H/F by weight, one or two of them,
 * components under LETTER_MIN_WEIGHT left out. */
export function letters(d) {
  const parts = [
    [Math.abs(d[0]), d[0] > 0 ? 'R' : 'L'],
    [Math.abs(d[1]), d[1] > 0 ? 'A' : 'P'],
    [Math.abs(d[2]), d[2] > 0 ? 'H' : 'F'],
  ].filter(([w]) => w >= LETTER_MIN_WEIGHT);
  // A stable sort: equal weights keep the R/L, A/P, H/F order.
  parts.sort((p, q) => q[0] - p[0]);
  return parts.slice(0, 2).map(([, l]) => l).join('');
}

/** The letters at the four edges of the displayed image of `pose`, flips applied
 * (`view.flipH`, `view.flipV`): `{ left, right, top, bottom }`. */
export function edgeLetters(pose, view = {}) {
  const { right, up } = screenAxes(pose);
  const neg = (v) => v.map((c) => -c);
  const r = view.flipH ? neg(right) : right;
  const t = view.flipV ? neg(up) : up;
  return { left: letters(neg(r)), right: letters(r), top: letters(t), bottom: letters(neg(t)) };
}

/** A number of degrees without a sign or a useless decimal. */
const deg = (v) => `${Math.round(Math.abs(v))}°`;

/** The view's name as radiographers say it: "AP", "LAO 30°", "RAO 20°", "lateral" (90 degrees
 * either way), with "cranial 10°" / "caudal 10°" after it when the arc is tilted. */
export function viewName(pose) {
  const o = Math.round(pose.orbital);
  const a = Math.round(pose.angular);
  let name;
  if (o === 0) name = 'AP';
  else if (Math.abs(o) >= 90) name = 'lateral';
  else name = `${o > 0 ? 'LAO' : 'RAO'} ${deg(o)}`;
  if (a !== 0) name += ` ${a > 0 ? 'cranial' : 'caudal'} ${deg(a)}`;
  return name;
}

/** Size of one image pixel at the isocentre plane, mm: the detector pixel (`fieldMm` over
 * `imagePx` pixels) divided by the magnification SID / SOD. */
export function isocentrePixelMm({ fieldMm, imagePx, sidMm = SOURCE_TO_DETECTOR_MM, sodMm = SOURCE_TO_ISOCENTRE_MM }) {
  return fieldMm / imagePx / (sidMm / sodMm);
}

/** The scale bar: the longest of SCALE_STEPS_MM whose length on the canvas stays within
 * SCALE_MAX_FRACTION of its width, for an image of `imagePx` pixels across shown on a canvas of
 * `canvasPx` pixels at `zoom`. Returns `{ mm, canvasPx, fraction }` (its length in canvas pixels
 * and as a fraction of the canvas width). */
export function scaleBar({ fieldMm, imagePx, canvasPx, zoom, sidMm, sodMm }) {
  const pxPerMm = ((canvasPx / imagePx) * zoom) / isocentrePixelMm({ fieldMm, imagePx, sidMm, sodMm });
  const fits = SCALE_STEPS_MM.filter((mm) => mm * pxPerMm <= SCALE_MAX_FRACTION * canvasPx);
  const mm = fits.length ? fits[fits.length - 1] : SCALE_STEPS_MM[0];
  return { mm, canvasPx: mm * pxPerMm, fraction: (mm * pxPerMm) / canvasPx };
}

/** The hub tilt of a screen direction (`dx` right, `dy` up, degrees, flips already undone) in
 * the view of `pose`: the patient direction d = dx u + dy up, then `cc` (> 0 aims cranially)
 * from d.z and `ml` (> 0 towards the patient's left) from -d.x, as the worker's `needle_tilt`
 * command takes them. A screen direction along the patient's front-back axis (screen-right in
 * a lateral view) gives no tilt: the command has no such component. */
export function screenToTilt(pose, dx, dy) {
  const { right, up } = screenAxes(pose);
  const d = [0, 1, 2].map((i) => dx * right[i] + dy * up[i]);
  // Rounded to 1e-9 degree so that cos(90 degrees) = 6e-17 reads as the 0 it is.
  const clean = (v) => Math.round(v * 1e9) / 1e9 + 0;
  return { cc: clean(d[2]), ml: clean(-d[0]) };
}
