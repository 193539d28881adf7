// The late gaze warp (docs/protocol.md, encoding `warp`; server/warp.py): as a VR runtime
// reprojects its last frame to the newest head pose, this shader places the retina-locked
// afterimage maps at the newest gaze at every display refresh, whatever the simulation rate.
// The server sends compose's first half (linear RGB before Eq. 12) and the maps; here come
// Eq. 12, the gamut mapping toward grey and the display gamma (reference.apply_afterimages),
// then the usual dither.

import { DITHER, program, texture } from './gl.js';

/** The warp payload's own header after the frame header: 4 u16, 3 + 3 + 9 + 9 f32, 2 × 4 f32. */
const HEAD_BYTES = 136;
const PANE_AT = 104;

/** Decode a warp frame's payload (starting at `header.header_bytes`): views, no copies but
 * where alignment needs one. */
export function decodeWarp(buffer, header) {
  const at = header.header_bytes;
  if (buffer.byteLength < at + HEAD_BYTES) throw new Error('warp frame too short');
  const dv = new DataView(buffer, at);
  const f32 = (i) => dv.getFloat32(8 + 4 * i, true);
  const panes = dv.getUint16(0, true);
  const gridW = dv.getUint16(4, true);
  const gridH = dv.getUint16(6, true);
  if (panes < 1 || panes > 2 || !gridW || !gridH) throw new Error('bad warp header');
  const pane = (i) => ({
    gaze: [dv.getFloat32(PANE_AT + 16 * i, true), dv.getFloat32(PANE_AT + 16 * i + 4, true)],
    visibility: dv.getFloat32(PANE_AT + 16 * i + 8, true),
  });
  const nRgb = header.width * header.height * 3;
  const nMaps = panes * 6 * gridW * gridH;
  const start = at + HEAD_BYTES;
  if (buffer.byteLength < start + 2 * (nRgb + nMaps)) throw new Error('warp frame too short');
  const halves = (offset, n) =>
    offset % 2 ? new Uint16Array(buffer.slice(offset, offset + 2 * n)) : new Uint16Array(buffer, offset, n);
  return {
    panes,
    paneWidth: dv.getUint16(2, true),
    gridW,
    gridH,
    cell: f32(0),
    sigma: f32(1),
    gamma: f32(2),
    wP: [f32(3), f32(4), f32(5)],
    rgb2lms: Array.from({ length: 9 }, (_, i) => f32(6 + i)),
    lms2rgb: Array.from({ length: 9 }, (_, i) => f32(15 + i)),
    pane: [pane(0), pane(1)],
    rgb: halves(start, nRgb),
    maps: halves(start + 2 * nRgb, nMaps),
  };
}

const FRAGMENT = `#version 300 es
precision highp float;
precision highp int;
uniform highp sampler2D u_rgb;   // linear RGB before Eq. 12, frame px, top row first
uniform highp sampler2D u_maps;  // per pane: gain - 1 (grid_h rows), then the additive term
uniform vec2 u_size;             // frame px
uniform bool u_smooth;           // the frame is magnified: sample it between pixels
uniform float u_pane_w;
uniform int u_panes;
uniform vec2 u_grid;             // retina grid cells
uniform float u_cell;            // screen px per cell
uniform float u_sigma;           // the foveal fall-off's sigma, px
uniform float u_gamma;
uniform vec3 u_wP;
uniform mat3 u_rgb2lms;          // row-major data, so that v * M is M v
uniform mat3 u_lms2rgb;
uniform vec2 u_gaze;             // pane px: the newest gaze
uniform vec2 u_visibility;       // per pane: Sec. 5's boost
in vec2 v_uv;
out vec4 o_colour;
${DITHER}

// Largest t in [0, 1] keeping a + t e inside the cube (sec2_4_display.cl gamut_t).
float gamut_t(float a, float e, float t) {
  if (e == 0.0) return t;
  float lim = (e > 0.0 ? 1.0 - a : -a) / e;
  return min(lim, t);
}

void main() {
  // Frame px from the top-left: a pixel's centre, or where a magnified frame is sampled
  // (bilinearly, as renderer.js draws a plain frame then).
  vec2 at = vec2(v_uv.x, 1.0 - v_uv.y) * u_size;
  vec2 q = u_smooth ? at : floor(min(at, u_size - 0.5)) + 0.5;
  int pane = (u_panes == 2 && q.x >= u_pane_w) ? 1 : 0;
  if (q.x >= u_pane_w * float(u_panes)) { o_colour = dither(vec3(0.0)); return; }
  vec3 J = u_smooth ? texture(u_rgb, q / u_size).rgb : texelFetch(u_rgb, ivec2(q), 0).rgb;
  // Eq. 12's maps at this pixel's retinal position, pixel - gaze; off the grid: equilibrium
  // (gain - 1 = 0, nothing added), as compose's border taps.
  vec2 d = vec2(q.x - float(pane) * u_pane_w, q.y) - u_gaze;
  vec2 u = d / u_cell + 0.5 * u_grid - 0.5;
  vec2 u0 = floor(u);
  vec2 fr = u - u0;
  ivec2 i0 = ivec2(u0), grid = ivec2(u_grid);
  int row0 = 2 * pane * grid.y;
  // The four taps, clamped into the grid; a tap off the grid weighs 0.
  ivec2 lo = clamp(i0, ivec2(0), grid - 1), hi = clamp(i0 + 1, ivec2(0), grid - 1);
  vec2 in0 = vec2(greaterThanEqual(i0, ivec2(0))) * vec2(lessThan(i0, grid));
  vec2 in1 = vec2(greaterThanEqual(i0 + 1, ivec2(0))) * vec2(lessThan(i0 + 1, grid));
  vec2 w0 = (1.0 - fr) * in0, w1 = fr * in1;
  vec3 gain = w0.y * (w0.x * texelFetch(u_maps, ivec2(lo.x, row0 + lo.y), 0).rgb
                      + w1.x * texelFetch(u_maps, ivec2(hi.x, row0 + lo.y), 0).rgb)
            + w1.y * (w0.x * texelFetch(u_maps, ivec2(lo.x, row0 + hi.y), 0).rgb
                      + w1.x * texelFetch(u_maps, ivec2(hi.x, row0 + hi.y), 0).rgb);
  int row1 = row0 + grid.y;
  vec3 add = w0.y * (w0.x * texelFetch(u_maps, ivec2(lo.x, row1 + lo.y), 0).rgb
                     + w1.x * texelFetch(u_maps, ivec2(hi.x, row1 + lo.y), 0).rgb)
           + w1.y * (w0.x * texelFetch(u_maps, ivec2(lo.x, row1 + hi.y), 0).rgb
                     + w1.x * texelFetch(u_maps, ivec2(hi.x, row1 + hi.y), 0).rgb);
  float f = u_visibility[pane] * exp(-dot(d, d) / (2.0 * u_sigma * u_sigma));
  vec3 lms = (J * u_rgb2lms) * (1.0 + f * gain);
  J = lms * u_lms2rgb + f * add;
  // Gamut (reference.gamut_map): toward the grey of luminance min(Y, Y_c), just far enough.
  float Y = dot(u_wP, J);
  vec3 e = J - Y;
  float dmin = min(min(e.r, e.g), e.b), spread = max(max(e.r, e.g), e.b) - dmin;
  float a = min(clamp(Y, 0.0, 1.0), clamp(-dmin / max(spread, 1.175494e-38), 0.0, 1.0));
  e = J - a;
  float t = max(gamut_t(a, e.b, gamut_t(a, e.g, gamut_t(a, e.r, 1.0))), 0.0);
  vec3 v = pow(clamp(a + t * e, 0.0, 1.0), vec3(u_gamma));
  o_colour = dither(v);
}`;

const UNIFORMS = ['u_rgb', 'u_maps', 'u_size', 'u_smooth', 'u_pane_w', 'u_panes', 'u_grid', 'u_cell', 'u_sigma',
  'u_gamma', 'u_wP', 'u_rgb2lms', 'u_lms2rgb', 'u_gaze', 'u_visibility', 'u_counter'];

/** A warp frame's textures and the program that composes it at a gaze. */
export class WarpLayer {
  constructor(gl) {
    this.gl = gl;
    this.program = program(gl, FRAGMENT);
    this.u = Object.fromEntries(UNIFORMS.map((n) => [n, gl.getUniformLocation(this.program, n)]));
    this.rgb = texture(gl);
    this.maps = texture(gl);
    this.vao = gl.createVertexArray();
    this.layers = null;
  }

  upload(width, height, layers) {
    const gl = this.gl;
    const rows = 2 * layers.panes * layers.gridH;
    const old = this.layers;
    const same = old && old.width === width && old.height === height && old.gridW === layers.gridW && old.rows === rows;
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1); // rows of 6·width bytes
    for (const [tex, w, h, data] of [[this.rgb, width, height, layers.rgb], [this.maps, layers.gridW, rows, layers.maps]]) {
      gl.bindTexture(gl.TEXTURE_2D, tex);
      if (same) gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, w, h, gl.RGB, gl.HALF_FLOAT, data);
      else gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB16F, w, h, 0, gl.RGB, gl.HALF_FLOAT, data);
    }
    this.layers = { ...layers, width, height, rows, rgb: null, maps: null };
  }

  /** The pane px of a gaze given as frame fractions, as the server maps it (eye.pane_gaze). */
  paneGaze(gaze) {
    const L = this.layers;
    if (!gaze) return L.pane[0].gaze;
    let x = gaze.x * L.width;
    if (L.panes === 2 && x >= L.paneWidth) x -= L.paneWidth;
    return [x, gaze.y * L.height];
  }

  /** Draw at `gaze` (frame fractions; null: the frame's own) with dither noise `counter`;
   * `magnified`: the frame is drawn larger than it is, sampled bilinearly. */
  draw(counter, gaze, magnified = false) {
    const gl = this.gl;
    const L = this.layers;
    const u = this.u;
    gl.useProgram(this.program);
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_2D, this.maps);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, this.rgb);
    const filter = magnified ? gl.LINEAR : gl.NEAREST;
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, filter);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter);
    gl.uniform1i(u.u_smooth, magnified ? 1 : 0);
    gl.uniform1i(u.u_rgb, 0);
    gl.uniform1i(u.u_maps, 1);
    gl.uniform2f(u.u_size, L.width, L.height);
    gl.uniform1f(u.u_pane_w, L.paneWidth);
    gl.uniform1i(u.u_panes, L.panes);
    gl.uniform2f(u.u_grid, L.gridW, L.gridH);
    gl.uniform1f(u.u_cell, L.cell);
    gl.uniform1f(u.u_sigma, L.sigma);
    gl.uniform1f(u.u_gamma, L.gamma);
    gl.uniform3fv(u.u_wP, L.wP);
    gl.uniformMatrix3fv(u.u_rgb2lms, false, L.rgb2lms);
    gl.uniformMatrix3fv(u.u_lms2rgb, false, L.lms2rgb);
    gl.uniform2fv(u.u_gaze, this.paneGaze(gaze));
    gl.uniform2f(u.u_visibility, L.pane[0].visibility, L.pane[1].visibility);
    gl.uniform1ui(u.u_counter, counter >>> 0);
    gl.bindVertexArray(this.vao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.bindVertexArray(null);
  }
}
