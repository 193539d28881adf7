// WebGL2 display of the server's frames with the paper's temporal dithering (Sec. 2.4):
// out = floor(255·v + u)/255 with u uniform in [0, 1) drawn afresh for every pixel, channel and
// displayed frame, so the mean over time equals v and an 8-bit screen shows >8-bit darks.

import { ENCODING } from './protocol.js';
import { DITHER, program, texture } from './gl.js';
import { WarpLayer } from './warp.js';

/** BT.709 luma weights of the streams' Y'CbCr (gazehdr.yuv.KR, KB). */
export const KR = 0.2126;
export const KB = 0.0722;
/** `frame.encoding` of a decoded stream picture (h264, av1): three 10-bit planes. */
const YUV = 'yuv';

// The fragment shader: the dither (gl.js, one for every source) of `frameValue()`, the frame's
// display value v at this fragment, top row first.
const fragment = (source) => `#version 300 es
precision highp float;
precision highp int;
precision highp usampler2D;
in vec2 v_uv;
out vec4 o_colour;
${DITHER}
${source}

void main() { o_colour = dither(clamp(frameValue(), 0.0, 1.0)); }`;

// Raw frames (f16, rgb10a2): an RGB texture, filtered as draw() chooses.
const RAW_SOURCE = `
uniform sampler2D u_frame;
// Rows arrive top row first; GL textures start at the bottom: flip here, not by copying.
vec3 frameValue() { return texture(u_frame, vec2(v_uv.x, 1.0 - v_uv.y)).rgb; }`;

// Stream frames (h264, av1): the decoder's 10-bit Y'CbCr 4:2:0 planes as integer textures (never an
// 8-bit image), back to RGB as gazehdr.video.to_rgb does: BT.709 weights, full range, each chroma
// sample over its 2×2 block; nearest pixel.
const YUV_SOURCE = `
uniform usampler2D u_y;
uniform usampler2D u_cb;
uniform usampler2D u_cr;
uniform ivec2 u_size;  // the frame's width and height (the planes may be larger)
const float KR = ${KR}, KB = ${KB}, KG = 1.0 - KR - KB;
vec3 frameValue() {
  ivec2 p = min(ivec2(vec2(v_uv.x, 1.0 - v_uv.y) * vec2(u_size)), u_size - 1);
  float y = float(texelFetch(u_y, p, 0).r) / 1023.0;
  float cb = (float(texelFetch(u_cb, p / 2, 0).r) - 512.0) / 1023.0;
  float cr = (float(texelFetch(u_cr, p / 2, 0).r) - 512.0) / 1023.0;
  float r = y + 2.0 * (1.0 - KR) * cr;
  float b = y + 2.0 * (1.0 - KB) * cb;
  return vec3(r, (y - KR * r - KB * b) / KG, b);
}`;

/** A linked program of `source` and the locations of its `uniforms`. */
function link(gl, source, uniforms) {
  const p = program(gl, fragment(source));
  return { program: p, at: Object.fromEntries(uniforms.map((u) => [u, gl.getUniformLocation(p, u)])) };
}

export class Renderer {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {{preserveDrawingBuffer?: boolean}} options
   */
  constructor(canvas, { preserveDrawingBuffer = false } = {}) {
    const gl = canvas.getContext('webgl2', {
      alpha: false,
      antialias: false,
      depth: false,
      stencil: false,
      premultipliedAlpha: false,
      preserveDrawingBuffer,
      powerPreference: 'high-performance',
    });
    if (!gl) throw new Error('WebGL2 is not available in this browser');
    this.canvas = canvas;
    this.gl = gl;
    this.counter = 0;
    this.frame = null; // {width, height, encoding} of the uploaded texture
    // The inspector's zoom: the fitted rectangle scaled by `scale` and moved by (x, y),
    // fractions of the canvas. Zoomed, the frame's pixels are drawn as blocks (NEAREST).
    this.view = { scale: 1, x: 0, y: 0 };

    this.raw = link(gl, RAW_SOURCE, ['u_counter']);
    this.yuv = link(gl, YUV_SOURCE, ['u_counter', 'u_y', 'u_cb', 'u_cr', 'u_size']);
    this.warp = null; // the late gaze warp's layers and program (warp.js), made on first use
    this.vao = gl.createVertexArray();
    this.texture = texture(gl); // draw() sets its filter
    this.filter = gl.NEAREST;
    this.planes = [0, 1, 2].map(() => texture(gl)); // a stream's Y', Cb, Cr
  }

  /**
   * Upload one frame. `pixels`: Uint16Array of width·height·3 halves (f16) or Uint32Array of
   * width·height packed RGB10_A2 words (rgb10a2), top row first.
   */
  upload(width, height, encoding, pixels) {
    const gl = this.gl;
    if (encoding === ENCODING.WARP) { // pixels: warp.js's decoded layers
      this.warp ??= new WarpLayer(gl);
      this.warp.upload(width, height, pixels);
      this.frame = { width, height, encoding };
      return;
    }
    let internal, format, type;
    if (encoding === ENCODING.F16) [internal, format, type] = [gl.RGB16F, gl.RGB, gl.HALF_FLOAT];
    else if (encoding === ENCODING.RGB10A2) {
      [internal, format, type] = [gl.RGB10_A2, gl.RGBA, gl.UNSIGNED_INT_2_10_10_10_REV];
    } else throw new Error(`unknown encoding ${encoding}`);
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1); // f16 rows are 6·width bytes
    const f = this.frame;
    if (f && f.width === width && f.height === height && f.encoding === encoding) {
      gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, width, height, format, type, pixels);
    } else {
      gl.texImage2D(gl.TEXTURE_2D, 0, internal, width, height, 0, format, type, pixels);
      this.frame = { width, height, encoding };
    }
  }

  /**
   * Upload one stream frame as web/video.js copied it out of its VideoFrame: `data` (Uint16Array)
   * holds the 10-bit Y', Cb and Cr planes at `layout` ([{offset, stride}] in bytes), the
   * picture `width`×`height` (the frame's), chroma half that, rounded up.
   */
  uploadYuv({ width, height, data, layout }) {
    const gl = this.gl;
    const sizes = [[width, height], ...Array(2).fill([Math.ceil(width / 2), Math.ceil(height / 2)])];
    const f = this.frame;
    const again = f && f.encoding === YUV && f.width === width && f.height === height;
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 2);
    for (let i = 0; i < 3; i++) {
      const [w, h] = sizes[i];
      gl.bindTexture(gl.TEXTURE_2D, this.planes[i]);
      gl.pixelStorei(gl.UNPACK_ROW_LENGTH, layout[i].stride / 2);
      if (again) {
        gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, w, h, gl.RED_INTEGER, gl.UNSIGNED_SHORT, data, layout[i].offset / 2);
      } else {
        gl.texImage2D(gl.TEXTURE_2D, 0, gl.R16UI, w, h, 0, gl.RED_INTEGER, gl.UNSIGNED_SHORT, data, layout[i].offset / 2);
      }
    }
    gl.pixelStorei(gl.UNPACK_ROW_LENGTH, 0);
    this.frame = { width, height, encoding: YUV };
  }

  /** Match the drawing buffer to the canvas's CSS size × devicePixelRatio; true if changed. */
  fitToCSS() {
    const c = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(c.clientWidth * dpr));
    const h = Math.max(1, Math.round(c.clientHeight * dpr));
    if (c.width === w && c.height === h) return false;
    c.width = w;
    c.height = h;
    return true;
  }

  /** The frame's rectangle in drawing-buffer pixels ("contain": keep aspect, centre, bars),
   * unzoomed. */
  fitRect() {
    const { drawingBufferWidth: cw, drawingBufferHeight: ch } = this.gl;
    if (!this.frame) return { x: 0, y: 0, width: cw, height: ch };
    const s = Math.min(cw / this.frame.width, ch / this.frame.height);
    const width = Math.max(1, Math.round(this.frame.width * s));
    const height = Math.max(1, Math.round(this.frame.height * s));
    // y from the top, like CSS; GL's viewport is converted in draw().
    return { x: Math.floor((cw - width) / 2), y: Math.floor((ch - height) / 2), width, height };
  }

  /** The frame's rectangle in drawing-buffer pixels as drawn: the fitted one, zoomed. */
  deviceRect() {
    const r = this.fitRect();
    const { scale: s, x, y } = this.view;
    if (s === 1 && x === 0 && y === 0) return r;
    const { drawingBufferWidth: cw, drawingBufferHeight: ch } = this.gl;
    return {
      x: Math.round(x * cw + s * r.x), y: Math.round(y * ch + s * r.y),
      width: Math.round(s * r.width), height: Math.round(s * r.height),
    }; // prettier-ignore
  }

  /** The largest zoom GL can draw: the zoomed rectangle within MAX_VIEWPORT_DIMS. */
  maxZoom() {
    const [mw, mh] = this.gl.getParameter(this.gl.MAX_VIEWPORT_DIMS);
    const r = this.fitRect();
    return Math.max(1, Math.min(mw / r.width, mh / r.height));
  }

  /** The drawn frame rectangle in CSS pixels relative to the canvas's top-left corner. */
  cssRect() {
    const r = this.deviceRect();
    const c = this.canvas;
    const sx = c.clientWidth ? c.clientWidth / this.gl.drawingBufferWidth : 1;
    const sy = c.clientHeight ? c.clientHeight / this.gl.drawingBufferHeight : 1;
    return { x: r.x * sx, y: r.y * sy, width: r.width * sx, height: r.height * sy };
  }

  /**
   * Draw the current frame with dither noise for `counter` (default: the next one). A warp
   * frame places its afterimages at `gaze` ({x, y}, fractions of the frame; null: the
   * frame's own gaze).
   */
  draw(counter = this.counter++, gaze = null) {
    const gl = this.gl;
    const { drawingBufferWidth: cw, drawingBufferHeight: ch } = gl;
    gl.viewport(0, 0, cw, ch);
    gl.clearColor(0, 0, 0, 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    if (!this.frame) return;
    const r = this.deviceRect();
    gl.viewport(r.x, ch - r.y - r.height, r.width, r.height);
    // Magnifying: LINEAR looks better; otherwise NEAREST keeps pixels (and dithering) exact.
    // Zoomed (the inspector), NEAREST: the frame's pixels as blocks.
    const magnified = this.view.scale === 1 && (r.width > this.frame.width || r.height > this.frame.height);
    if (this.frame.encoding === ENCODING.WARP) {
      this.warp.draw(counter, gaze, magnified);
      return;
    }
    const { program, at } = this.frame.encoding === YUV ? this.yuv : this.raw;
    gl.useProgram(program);
    if (program === this.yuv.program) {
      for (let i = 0; i < 3; i++) {
        gl.activeTexture(gl.TEXTURE0 + i);
        gl.bindTexture(gl.TEXTURE_2D, this.planes[i]);
      }
      gl.uniform1i(at.u_y, 0);
      gl.uniform1i(at.u_cb, 1);
      gl.uniform1i(at.u_cr, 2);
      gl.uniform2i(at.u_size, this.frame.width, this.frame.height);
      gl.activeTexture(gl.TEXTURE0);
    } else {
      const filter = magnified ? gl.LINEAR : gl.NEAREST;
      gl.bindTexture(gl.TEXTURE_2D, this.texture);
      if (filter !== this.filter) {
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, filter);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter);
        this.filter = filter;
      }
    }
    gl.uniform1ui(at.u_counter, counter >>> 0);
    gl.bindVertexArray(this.vao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.bindVertexArray(null);
  }

  /**
   * RGBA bytes of the drawing buffer, bottom row first (GL order). Call it in the same task
   * as draw(): without preserveDrawingBuffer the browser clears the buffer once composited.
   */
  readPixels() {
    const gl = this.gl;
    const { drawingBufferWidth: w, drawingBufferHeight: h } = gl;
    const out = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, out);
    return out;
  }
}
