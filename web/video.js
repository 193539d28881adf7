// The stream encodings in the browser (docs/protocol.md): packets of a 10-bit H.264 or AV1
// stream, decoded with WebCodecs' VideoDecoder and copied out of each VideoFrame as 16-bit
// planes, so the dither shader gets all 10 bits (drawing the VideoFrame as an image would give
// it 8).

import { ENCODING } from './protocol.js';

/** WebCodecs' names for the server's streams (gazehdr.video.CODECS, the same), by encoding. */
export const CODECS = Object.freeze({
  h264: { codec: 'avc1.6E0028', what: 'H.264 High 10' },
  av1: { codec: 'av01.0.08M.10', what: 'AV1, 10 bits' },
});
const NAMES = Object.freeze({ [ENCODING.H264]: 'h264', [ENCODING.AV1]: 'av1' });
/** Software decoding (FFmpeg's h264 and dav1d in Chromium) gives pictures in memory as
 * I420P10, which copyTo reads; a hardware decoder may give GPU-only frames (format null) that
 * it cannot. */
const ACCELERATION = 'prefer-software';

/**
 * Whether this page can decode stream `name` ('h264', 'av1'): null if it can, else why not, in
 * words for the viewer. WebCodecs exists only in a secure context (https, or http on localhost).
 */
export async function unsupported(name, width = 1920, height = 1080) {
  if (typeof VideoDecoder === 'undefined') {
    return globalThis.isSecureContext === false
      ? 'WebCodecs needs a secure context: open the viewer over https (or on localhost)'
      : 'this browser has no WebCodecs VideoDecoder';
  }
  const { codec, what } = CODECS[name];
  try {
    const config = { codec, codedWidth: width, codedHeight: height, hardwareAcceleration: ACCELERATION };
    const { supported } = await VideoDecoder.isConfigSupported(config);
    return supported ? null : `this browser does not decode ${codec} (${what})`;
  } catch (err) {
    return `VideoDecoder refused ${codec}: ${err.message}`;
  }
}

/**
 * One stream's decoder. `decode(header, packet)` in arrival order; `onPlanes({width, height,
 * data, layout, frame})` gets each decoded picture (for `Renderer.uploadYuv`); `onLost(why)`
 * is told when the stream broke (a corrupt packet, a gap): send a keyframe request. Until a
 * keyframe comes, delta packets are skipped (they would decode to garbage or not at all).
 */
export class VideoStream {
  constructor(onPlanes, onLost) {
    this.onPlanes = onPlanes;
    this.onLost = onLost;
    this.decoder = null;
    this.size = null; // [width, height] the decoder is configured for
    this.name = null; // and the stream ('h264', 'av1')
    this.keyed = false;
    this.stats = { packets: 0, decoded: 0, skipped: 0, lost: 0, lastError: null };
    this.pending = new Map(); // frame number → header, until its picture comes out
  }

  _open(name, width, height) {
    this.decoder?.state !== 'closed' && this.decoder?.close();
    const decoder = new VideoDecoder({
      output: (frame) => this._output(frame),
      error: (err) => decoder === this.decoder && this._lost(`decoder error: ${err.message}`),
    });
    decoder.configure({
      codec: CODECS[name].codec, codedWidth: width, codedHeight: height, optimizeForLatency: true,
      hardwareAcceleration: ACCELERATION,
    }); // prettier-ignore
    this.decoder = decoder;
    this.size = [width, height];
    this.name = name;
  }

  _lost(why) {
    this.stats.lost += 1;
    this.stats.lastError = why;
    this.keyed = false;
    this.pending.clear();
    if (this.decoder?.state !== 'closed') this.decoder?.close();
    this.decoder = null;
    this.onLost(why);
  }

  decode(header, packet) {
    this.stats.packets += 1;
    const { width, height } = header;
    const name = NAMES[header.encoding];
    if (!header.keyframe && (!this.keyed || this.decoder?.state !== 'configured' || this.name !== name)) {
      this.stats.skipped += 1; // the keyframe it waits for was asked for when it broke
      return;
    }
    if (header.keyframe && (!this.decoder || this.decoder.state !== 'configured' || this.name !== name || this.size[0] !== width || this.size[1] !== height)) {
      this._open(name, width, height);
    }
    try {
      const type = header.keyframe ? 'key' : 'delta';
      this.decoder.decode(new EncodedVideoChunk({ type, timestamp: header.frame, data: packet }));
      this.keyed = true;
      this.pending.set(header.frame, header);
    } catch (err) {
      this._lost(`bad packet for frame ${header.frame}: ${err.message}`);
    }
  }

  async _output(frame) {
    const header = this.pending.get(frame.timestamp);
    this.pending.delete(frame.timestamp);
    try {
      if (frame.format !== 'I420P10') {
        this._lost(`the decoder gave ${frame.format} pictures, not 10-bit I420P10`);
        return;
      }
      const data = new Uint16Array(frame.allocationSize() / 2);
      const layout = await frame.copyTo(data);
      this.stats.decoded += 1;
      const width = header?.width ?? frame.visibleRect.width;
      const height = header?.height ?? frame.visibleRect.height;
      this.onPlanes({ width, height, data, layout, frame: frame.timestamp });
    } finally {
      frame.close();
    }
  }
}
