// Images as on a C-arm monitor: the last image stays on screen until the next one (the live
// canvas keeps it); the learner stores images in a strip (one key) and shows any stored one as
// the reference beside the live image (for example the AP beside the oblique). Stored images are
// the frames as the worker sent them (no window/level), as blob URLs, and nothing leaves the page.

/** Most images the strip keeps; the oldest goes first. Simulator choice: a C-arm's reference
 * monitor holds a handful, and 12 thumbnails fit one row on a 1440 px screen. */
export const MAX_STORED = 12;

/** The label of a stored image: its number, view name and the session time it was stored at. */
export function storedLabel(n, view, whenMs) {
  const s = Math.max(0, Math.round(whenMs / 1000));
  const mmss = `${String(Math.floor(s / 60)).padStart(2, '0')}:${String(s % 60).padStart(2, '0')}`;
  return `Image ${n}: ${view}, stored at ${mmss}`;
}

/** Keeps at most `max` items of `items` after pushing `item`; returns the ones dropped. */
export function pushBounded(items, item, max = MAX_STORED) {
  items.push(item);
  return items.length > max ? items.splice(0, items.length - max) : [];
}

/** The strip and the reference pane (DOM: `list` an <ol>, `reference` an <img>, `caption` the
 * reference's caption, `announce(text)` for the live region). */
export class ImageStore {
  constructor({ list, reference, caption, announce }) {
    this.list = list;
    this.reference = reference;
    this.caption = caption;
    this.announce = announce;
    this.items = [];
    this.count = 0;
    this.started = performance.now();
  }

  /** Forgets every stored image (a new session). */
  reset() {
    for (const i of this.items) URL.revokeObjectURL(i.url);
    this.items = [];
    this.count = 0;
    this.started = performance.now();
    this.showReference(null);
    this.render();
  }

  /** Stores the image on `canvas` (the frame as received) taken in `view` (its name). */
  async store(canvas, view) {
    const blob = await new Promise((resolve) => canvas.toBlob(resolve, 'image/png'));
    if (!blob) return;
    this.count += 1;
    const item = { n: this.count, url: URL.createObjectURL(blob), label: storedLabel(this.count, view, performance.now() - this.started) };
    for (const gone of pushBounded(this.items, item)) {
      if (this.current === gone) this.showReference(null);
      URL.revokeObjectURL(gone.url);
    }
    this.render();
    this.announce(`${item.label}. ${this.items.length} in the strip.`);
  }

  /** Shows stored `item` as the reference (null: none). */
  showReference(item) {
    this.current = item;
    this.reference.hidden = !item;
    this.caption.textContent = item ? `Reference: ${item.label}` : 'No reference image: store images with the store key, then choose one.';
    if (item) {
      this.reference.src = item.url;
      this.reference.alt = `Reference image. ${item.label}`;
    } else {
      this.reference.removeAttribute('src');
    }
    for (const b of this.list.querySelectorAll('button')) {
      b.setAttribute('aria-pressed', String(!!item && b.dataset.n === String(item.n)));
    }
  }

  render() {
    this.list.replaceChildren(...this.items.map((item) => {
      const b = document.createElement('button');
      b.type = 'button';
      b.dataset.n = String(item.n);
      b.setAttribute('aria-pressed', String(this.current === item));
      b.setAttribute('aria-label', `Show as reference: ${item.label}`);
      const img = document.createElement('img');
      img.src = item.url;
      img.alt = '';
      img.width = 72;
      img.height = 72;
      const span = document.createElement('span');
      span.textContent = String(item.n);
      b.append(img, span);
      b.addEventListener('click', () => this.showReference(this.current === item ? null : item));
      const li = document.createElement('li');
      li.append(b);
      return li;
    }));
  }
}
