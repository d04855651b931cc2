// A live session over the server's websocket: sequenced commands, acknowledgements, JPEG
// frames with their header, latency and frame-rate measurement, and reconnection that re-sends
// every command not yet acknowledged (the worker acknowledges a re-sent sequence number as a
// duplicate, so nothing is applied twice and nothing is lost).

// The frame layout and the views' wire codes come from the session's hello
// (`session.protocol`, render_worker::session::offer::ProtocolInfo); this client keeps no copy.

/** Parses a binary frame message with the hello's `protocol`: header fields and the JPEG
 * bytes, or null when it is not a frame of this protocol. */
export function parseFrame(buffer, protocol) {
  if (!protocol) return null;
  const b = new Uint8Array(buffer);
  const headerBytes = protocol.frame_header_bytes;
  const magic = String.fromCharCode(b[0], b[1], b[2], b[3]);
  if (b.length < headerBytes || magic !== protocol.frame_magic || b[4] !== protocol.frame_header_version) return null;
  const view = protocol.views.find((v) => v.code === b[5]);
  const dv = new DataView(buffer);
  return {
    view: view ? view.name : 'unknown',
    frameSeq: Number(dv.getBigUint64(8, true)),
    inputSeq: Number(dv.getBigUint64(16, true)),
    tMs: Number(dv.getBigUint64(24, true)),
    width: dv.getUint16(32, true),
    height: dv.getUint16(34, true),
    // A draft: a cheaper preview of this input; the full frame of the same input follows.
    draft: (b[6] & (protocol.frame_draft_flag || 0)) !== 0,
    jpeg: b.subarray(headerBytes),
  };
}

export class LiveSession extends EventTarget {
  /** `wsPath` is the server's `/api/sessions/{id}/ws`. */
  constructor(wsPath) {
    super();
    this.wsPath = wsPath;
    this.seq = 0;
    this.pending = new Map(); // seq -> message text, until acknowledged or rejected
    this.sentAt = new Map(); // seq -> performance.now() when first sent
    this.lastFrameInput = 0;
    this.frameTimes = [];
    // `views`: per view, frames received and the header of the newest one.
    this.stats = { frames: 0, drafts: 0, acks: 0, errors: 0, latenciesMs: [], lastFrame: null, views: {} };
    /** Views on screen, sent after every hello (null: the session's default, all of them). */
    this.visible = null;
    this.closed = false;
    this.retryMs = 250;
    /** The protocol of the latest hello: frame layout, views, command kinds, constants. */
    this.protocol = null;
  }

  /** A number the hello's protocol lists for `modality` (`"session"` for the core's), or
   * `fallback` before the first hello. */
  constant(modality, name, fallback) {
    const c = this.protocol && this.protocol.constants && this.protocol.constants[modality];
    return c && typeof c[name] === 'number' ? c[name] : fallback;
  }

  connect() {
    const url = (location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + this.wsPath;
    const ws = new WebSocket(url);
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    ws.onopen = () => this.emit('connection', { state: 'open' });
    ws.onmessage = (ev) => {
      if (typeof ev.data === 'string') this.onText(ev.data);
      else this.onFrame(ev.data);
    };
    ws.onclose = (ev) => {
      this.emit('connection', { state: 'closed' });
      if (this.closed) return;
      // The server ended the session (4001: no command for its idle limit; 4003: the account
      // was revoked; 1011: its log cannot be stored; 4009: another window or tab opened it, and
      // this one reconnecting would only take it back from there): reconnecting cannot help;
      // opening the attempt again (after logging in) resumes it.
      if (ev.code === 4001 || ev.code === 4003 || ev.code === 1011 || ev.code === 4009) {
        this.closed = true;
        this.emit('ended', { code: ev.code, reason: ev.reason });
        return;
      }
      // Reconnect with back-off; unacknowledged commands are re-sent after the hello.
      setTimeout(() => this.connect(), this.retryMs);
      this.retryMs = Math.min(this.retryMs * 2, 4000);
    };
  }

  close() {
    this.closed = true;
    if (this.ws) this.ws.close();
  }

  emit(type, detail) {
    this.dispatchEvent(new CustomEvent(type, { detail }));
  }

  onText(text) {
    let m;
    try { m = JSON.parse(text); } catch { return; }
    switch (m.type) {
      case 'hello':
        this.retryMs = 250;
        this.protocol = m.session.protocol || null;
        this.seq = Math.max(this.seq, m.last_seq);
        for (const [seq, t] of [...this.pending.entries()].sort((a, b) => a[0] - b[0])) {
          if (seq > m.last_seq) this.ws.send(t); else this.pending.delete(seq);
        }
        if (this.visible) this.ws.send(JSON.stringify({ type: 'views', visible: this.visible }));
        this.emit('hello', m);
        break;
      case 'ack':
        this.pending.delete(m.seq);
        this.stats.acks += 1;
        this.emit('ack', m);
        break;
      case 'error':
        if (m.seq != null) this.pending.delete(m.seq);
        this.stats.errors += 1;
        this.emit('commanderror', m);
        break;
      default:
        this.emit(m.type, m);
    }
  }

  async onFrame(buffer) {
    const f = parseFrame(buffer, this.protocol);
    if (!f) return;
    const now = performance.now();
    // Input-to-frame latency: from sending the newest input this frame reflects to its arrival.
    if (f.inputSeq > this.lastFrameInput && this.sentAt.has(f.inputSeq)) {
      const ms = now - this.sentAt.get(f.inputSeq);
      this.stats.latenciesMs.push(ms);
      if (this.stats.latenciesMs.length > 200) this.stats.latenciesMs.shift();
    }
    for (const s of this.sentAt.keys()) if (s <= f.inputSeq) this.sentAt.delete(s);
    this.lastFrameInput = Math.max(this.lastFrameInput, f.inputSeq);
    this.frameTimes.push(now);
    while (this.frameTimes.length && now - this.frameTimes[0] > 2000) this.frameTimes.shift();
    this.stats.frames += 1;
    if (f.draft) this.stats.drafts += 1;
    this.stats.lastFrame = { view: f.view, frameSeq: f.frameSeq, inputSeq: f.inputSeq, width: f.width, height: f.height, draft: f.draft };
    const v = this.stats.views[f.view] || (this.stats.views[f.view] = { frames: 0, drafts: 0 });
    Object.assign(v, {
      frames: v.frames + 1, drafts: (v.drafts || 0) + (f.draft ? 1 : 0),
      frameSeq: f.frameSeq, inputSeq: f.inputSeq, width: f.width, height: f.height, draft: f.draft,
    });
    const bitmap = await createImageBitmap(new Blob([f.jpeg], { type: 'image/jpeg' }));
    this.emit('frame', { frame: f, bitmap });
  }

  /** Frames per second over the last two seconds. */
  fps() {
    const t = this.frameTimes;
    if (t.length < 2) return 0;
    return (t.length - 1) / ((t[t.length - 1] - t[0]) / 1000 || 1);
  }

  /** Median of the recent latencies, ms. */
  latencyMs() {
    const l = [...this.stats.latenciesMs].sort((a, b) => a - b);
    return l.length ? l[Math.floor(l.length / 2)] : null;
  }

  /** Tells the worker which views are on screen (only those are rendered); kept for
   * reconnections. */
  setVisible(views) {
    this.visible = [...views];
    if (this.ws && this.ws.readyState === WebSocket.OPEN) this.ws.send(JSON.stringify({ type: 'views', visible: this.visible }));
  }

  /** Sends a command; returns its sequence number. */
  send(command) {
    this.seq += 1;
    const seq = this.seq;
    const text = JSON.stringify({ type: 'command', seq, command });
    this.pending.set(seq, text);
    this.sentAt.set(seq, performance.now());
    if (this.ws && this.ws.readyState === WebSocket.OPEN) this.ws.send(text);
    return seq;
  }
}
