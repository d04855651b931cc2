// The frame parser of the session protocol (web-client/session.js `parseFrame`), on frames
// built here with the layout of render_worker::session::frame (40-byte header: magic, version,
// view code, flags, frame and input sequence numbers, time, width, height).
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { parseFrame } from '../../session.js';

/** The protocol as a hello lists it (render_worker::session::offer::ProtocolInfo). */
const PROTOCOL = {
  frame_magic: 'SIMF', frame_header_version: 1, frame_header_bytes: 40, frame_draft_flag: 1,
  views: [{ name: 'fluoroscopy', code: 0 }, { name: 'ultrasound', code: 1 }],
};

function frame({ magic = 'SIMF', version = 1, code = 0, flags = 0, frameSeq = 7, inputSeq = 5, tMs = 1234, width = 512, height = 256, jpeg = [0xff, 0xd8, 0xff] } = {}) {
  const buf = new ArrayBuffer(40 + jpeg.length);
  const b = new Uint8Array(buf);
  for (let i = 0; i < 4; i++) b[i] = magic.charCodeAt(i);
  b[4] = version;
  b[5] = code;
  b[6] = flags;
  const dv = new DataView(buf);
  dv.setBigUint64(8, BigInt(frameSeq), true);
  dv.setBigUint64(16, BigInt(inputSeq), true);
  dv.setBigUint64(24, BigInt(tMs), true);
  dv.setUint16(32, width, true);
  dv.setUint16(34, height, true);
  b.set(jpeg, 40);
  return buf;
}

test("a frame's header fields and JPEG bytes", () => {
  const f = parseFrame(frame(), PROTOCOL);
  assert.equal(f.view, 'fluoroscopy');
  assert.equal(f.frameSeq, 7);
  assert.equal(f.inputSeq, 5);
  assert.equal(f.tMs, 1234);
  assert.equal(f.width, 512);
  assert.equal(f.height, 256);
  assert.equal(f.draft, false);
  assert.deepEqual([...f.jpeg], [0xff, 0xd8, 0xff]);
});

test('the draft flag and view codes', () => {
  const f = parseFrame(frame({ code: 1, flags: 1 }), PROTOCOL);
  assert.equal(f.view, 'ultrasound');
  assert.equal(f.draft, true);
  assert.equal(parseFrame(frame({ code: 9 }), PROTOCOL).view, 'unknown');
});

test('not a frame of this protocol', () => {
  assert.equal(parseFrame(frame(), null), null);
  assert.equal(parseFrame(frame({ magic: 'XXXX' }), PROTOCOL), null);
  assert.equal(parseFrame(frame({ version: 2 }), PROTOCOL), null);
  assert.equal(parseFrame(new ArrayBuffer(10), PROTOCOL), null);
});
