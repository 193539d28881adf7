// The browser side of /ws/view (docs/protocol.md). No I/O here: bytes in, typed objects out,
// and plain objects for the control messages, so the wire format lives in one place.

import { decodeWarp } from './warp.js';

export const PROTOCOL = 1;
export const MAGIC = 'GZHF';
/** Header size of version 1; later versions may append fields, so readers use header_bytes. */
export const HEADER_BYTES_V1 = 56;
export const ENCODING = Object.freeze({ F16: 1, RGB10A2: 2, AV1: 3, H264: 4, WARP: 16 });
export const ENCODING_NAMES = Object.freeze({ 1: 'f16', 2: 'rgb10a2', 3: 'av1', 4: 'h264', 16: 'warp' });
/** The encodings that are packets of a video stream (web/video.js decodes them). */
export const STREAM_ENCODINGS = Object.freeze([ENCODING.AV1, ENCODING.H264]);
export const isStream = (encoding) => STREAM_ENCODINGS.includes(encoding);
export const BYTES_PER_PIXEL = Object.freeze({ 1: 6, 2: 4 });
/** The server refuses gaze outside [-3, 4] frame fractions; clamp rather than get an error. */
const GAZE_MIN = -3;
const GAZE_MAX = 4;

export class ProtocolError extends Error {}

/** Decode the fixed header of a binary frame message (all little-endian). */
export function decodeHeader(buffer) {
  if (!(buffer instanceof ArrayBuffer)) throw new ProtocolError('frame is not an ArrayBuffer');
  if (buffer.byteLength < HEADER_BYTES_V1) {
    throw new ProtocolError(`frame of ${buffer.byteLength} bytes is shorter than its header`);
  }
  const dv = new DataView(buffer);
  const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
  if (magic !== MAGIC) throw new ProtocolError(`bad frame magic ${JSON.stringify(magic)}`);
  const version = dv.getUint16(4, true);
  const header_bytes = dv.getUint16(6, true);
  if (version < 1) throw new ProtocolError(`bad frame version ${version}`);
  if (header_bytes < HEADER_BYTES_V1 || header_bytes > buffer.byteLength) {
    throw new ProtocolError(`bad header_bytes ${header_bytes}`);
  }
  const flags = dv.getUint8(45);
  return {
    version,
    header_bytes,
    frame: dv.getUint32(8, true),
    gaze_seq: dv.getUint32(12, true),
    time: dv.getFloat64(16, true),
    gaze_x: dv.getFloat32(24, true),
    gaze_y: dv.getFloat32(28, true),
    adaptation: dv.getFloat32(32, true),
    rho: dv.getFloat32(36, true),
    width: dv.getUint16(40, true),
    height: dv.getUint16(42, true),
    encoding: dv.getUint8(44),
    flags,
    eyes_open: (flags & 1) !== 0,
    tracker_gaze: (flags & 2) !== 0,
    split: (flags & 4) !== 0, // two panes side by side, each floor(width / 2) px wide
    keyframe: (flags & 8) !== 0, // a stream's (h264, av1): the packet needs no earlier one
    server_ms: dv.getFloat32(48, true),
    dropped: dv.getUint32(52, true),
  };
}

/**
 * Decode a whole frame: the header and a typed view of the pixels, ready for texImage2D
 * (Uint16Array of halves for f16, Uint32Array of packed words for rgb10a2). No copy unless a
 * future header size breaks the view's alignment.
 */
export function decodeFrame(buffer) {
  const header = decodeHeader(buffer);
  if (header.encoding === ENCODING.WARP) { // the late gaze warp's layers (warp.js)
    if (header.width === 0 || header.height === 0) throw new ProtocolError('empty frame');
    try {
      return { header, pixels: decodeWarp(buffer, header) };
    } catch (err) {
      throw new ProtocolError(err.message);
    }
  }
  if (isStream(header.encoding)) {
    // A packet of a stream (web/video.js decodes it): the bytes, as they came.
    if (buffer.byteLength === header.header_bytes) {
      throw new ProtocolError(`empty ${ENCODING_NAMES[header.encoding]} packet`);
    }
    return { header, packet: new Uint8Array(buffer, header.header_bytes) };
  }
  const bpp = BYTES_PER_PIXEL[header.encoding];
  if (!bpp) throw new ProtocolError(`unknown frame encoding ${header.encoding}`);
  if (header.width === 0 || header.height === 0) throw new ProtocolError('empty frame');
  const bytes = header.width * header.height * bpp;
  if (buffer.byteLength - header.header_bytes < bytes) {
    throw new ProtocolError(
      `frame ${header.width}×${header.height} ${ENCODING_NAMES[header.encoding]} needs ` +
        `${bytes} payload bytes, got ${buffer.byteLength - header.header_bytes}`,
    );
  }
  const Typed = header.encoding === ENCODING.F16 ? Uint16Array : Uint32Array;
  let source = buffer;
  let offset = header.header_bytes;
  if (offset % Typed.BYTES_PER_ELEMENT !== 0) {
    source = buffer.slice(offset, offset + bytes);
    offset = 0;
  }
  return { header, pixels: new Typed(source, offset, bytes / Typed.BYTES_PER_ELEMENT) };
}

export const SCENE_MAGIC = 'GZHS';
const SCENE_HEADER_BYTES_V1 = 24;

/** The binary message's kind: 'frame' (GZHF), 'scene' (GZHS, a scene map) or null. */
export function binaryKind(buffer) {
  if (!(buffer instanceof ArrayBuffer) || buffer.byteLength < 4) return null;
  const m = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  return m === MAGIC ? 'frame' : m === SCENE_MAGIC ? 'scene' : null;
}

/**
 * A scene map (docs/protocol.md): one pane's radiance (cd/m², RGB interleaved, from float16
 * times 2^exponent) and mesopic ρ per pixel, both width·height, top row first.
 */
export function decodeSceneMap(buffer) {
  if (binaryKind(buffer) !== 'scene' || buffer.byteLength < SCENE_HEADER_BYTES_V1) {
    throw new ProtocolError('not a scene map');
  }
  const dv = new DataView(buffer);
  const version = dv.getUint16(4, true);
  const headerBytes = dv.getUint16(6, true);
  if (version !== 1) throw new ProtocolError(`scene map version ${version}`);
  const width = dv.getUint16(12, true);
  const height = dv.getUint16(14, true);
  const exponent = dv.getInt16(16, true);
  const n = width * height;
  if (buffer.byteLength < headerBytes + n * 10) throw new ProtocolError('scene map too short');
  const halves = new Uint16Array(buffer.slice(headerBytes, headerBytes + n * 6));
  const radiance = new Float32Array(n * 3);
  const factor = 2 ** exponent;
  for (let i = 0; i < radiance.length; i++) radiance[i] = halfToFloat(halves[i]) * factor;
  const rho = new Float32Array(buffer.slice(headerBytes + n * 6, headerBytes + n * 10));
  return { seq: dv.getUint32(8, true), width, height, exponent, radiance, rho };
}

/** IEEE 754 half (as a u16) to a number; for debugging and tests. */
export function halfToFloat(h) {
  const sign = h & 0x8000 ? -1 : 1;
  const exp = (h >> 10) & 0x1f;
  const frac = h & 0x3ff;
  if (exp === 0) return sign * frac * 2 ** -24;
  if (exp === 31) return frac ? NaN : sign * Infinity;
  return sign * (1 + frac / 1024) * 2 ** (exp - 15);
}

const clampGaze = (v) => Math.min(GAZE_MAX, Math.max(GAZE_MIN, v));

/** Control messages, browser → server (JSON text). */
export const messages = {
  viewport: (width, height) => ({
    type: 'viewport',
    width: Math.max(1, Math.round(width)),
    height: Math.max(1, Math.round(height)),
  }),
  gaze: (x, y, seq) => ({ type: 'gaze', x: clampGaze(x), y: clampGaze(y), seq }),
  eyes: (open) => ({ type: 'eyes', open: Boolean(open) }),
  scene: (name) => ({ type: 'scene', name }),
  /** `model`, `split`: {afterimage, acuity}; split null: one model over the whole frame. */
  model: (model, split) => ({
    type: 'model',
    afterimage: model.afterimage,
    acuity: model.acuity,
    split: split ? { afterimage: split.afterimage, acuity: split.acuity } : null,
  }),
  gazeSource: (name) => ({ type: 'gaze_source', name }),
  params: (values) => ({ type: 'params', values }),
  /** The current scene's `scale` (cd/m² per unit), estimate `kind`, `layer`; null: default. */
  sceneSettings: (values) => ({ type: 'scene_settings', ...values }),
  sceneMaps: (send) => ({ type: 'scene_maps', send: Boolean(send) }),
  /** Late gaze warp frames (encoding `warp`) to this viewer or not. */
  warp: (on) => ({ type: 'warp', on: Boolean(on) }),
  reset: () => ({ type: 'reset' }),
  ack: (frame) => ({ type: 'ack', frame }),
  /** 'f16', 'rgb10a2', 'h264', 'av1' or null (the session's raw frames); per viewer. */
  encoding: (name) => ({ type: 'encoding', name }),
  /** A stream's viewer lost it: the next packet it gets is a keyframe. */
  keyframe: () => ({ type: 'keyframe' }),
};

/** Parse a text message; null if it is not a JSON object with a string `type`. */
export function parseText(text) {
  let msg;
  try {
    msg = JSON.parse(text);
  } catch {
    return null;
  }
  return msg && typeof msg === 'object' && typeof msg.type === 'string' ? msg : null;
}
