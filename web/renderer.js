// WebGL2 display of the server's frames with the paper's temporal dithering (Sec. 2.4):
// out = floor(255·v + u)/255 with u uniform in [0, 1) drawn afresh for every pixel, channel and
// displayed frame, so the mean over time equals v and an 8-bit screen shows >8-bit darks.

import { ENCODING } from './protocol.js';
import { DITHER, program } from './gl.js';
import { WarpLayer } from './warp.js';

const FRAGMENT = `#version 300 es
precision highp float;
precision highp int;
uniform sampler2D u_frame;
in vec2 v_uv;
out vec4 o_colour;
${DITHER}

void main() {
  // Rows arrive top row first; GL textures start at the bottom: flip here, not by copying.
  vec3 v = clamp(texture(u_frame, vec2(v_uv.x, 1.0 - v_uv.y)).rgb, 0.0, 1.0);
  o_colour = dither(v);
}`;

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

    this.program = program(gl, FRAGMENT);
    this.uCounter = gl.getUniformLocation(this.program, 'u_counter');
    this.warp = null; // the late gaze warp's layers and program (warp.js), made on first use
    this.vao = gl.createVertexArray();
    this.texture = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    this.filter = null;
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

  /** The frame's rectangle in drawing-buffer pixels ("contain": keep aspect, centre, bars). */
  deviceRect() {
    const { drawingBufferWidth: cw, drawingBufferHeight: ch } = this.gl;
    if (!this.frame) return { x: 0, y: 0, width: cw, height: ch };
    const s = Math.min(cw / this.frame.width, ch / this.frame.height);
    const width = Math.max(1, Math.round(this.frame.width * s));
    const height = Math.max(1, Math.round(this.frame.height * s));
    // y from the top, like CSS; GL's viewport is converted in draw().
    return { x: Math.floor((cw - width) / 2), y: Math.floor((ch - height) / 2), width, height };
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
    const magnified = r.width > this.frame.width || r.height > this.frame.height;
    if (this.frame.encoding === ENCODING.WARP) {
      this.warp.draw(counter, gaze, magnified);
      return;
    }
    const filter = magnified ? gl.LINEAR : gl.NEAREST;
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    if (filter !== this.filter) {
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, filter);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter);
      this.filter = filter;
    }
    gl.useProgram(this.program);
    gl.uniform1ui(this.uCounter, counter >>> 0);
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
