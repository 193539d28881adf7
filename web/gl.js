// GLSL and GL helpers the frame shaders share (renderer.js: plain frames; warp.js: the late
// gaze warp), so both dither alike.

export const VERTEX = `#version 300 es
// One triangle covering the viewport; no vertex buffers needed.
out vec2 v_uv;
void main() {
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  v_uv = p;
  gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}`;

/** The paper's temporal dither (Sec. 2.4): dither(v) = floor(255·v + u)/255, u uniform in
 * [0, 1) afresh per pixel, channel and displayed frame (`u_counter`). */
export const DITHER = `
uniform uint u_counter;  // displayed-frame counter: new noise every draw

// lowbias32 (C. Wellons): a full-avalanche integer hash, so neighbouring pixels, channels and
// frames get uncorrelated noise (a sine hash or a small LCG would show patterns).
uint lowbias32(uint x) {
  x ^= x >> 16; x *= 0x7feb352du;
  x ^= x >> 15; x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}
// Top 24 bits to [0, 1): exact in a float, never reaches 1.
float unit(uint h) { return float(h >> 8u) * (1.0 / 16777216.0); }

vec4 dither(vec3 v) {
  uvec2 p = uvec2(gl_FragCoord.xy);
  uint h = lowbias32(lowbias32(lowbias32(u_counter) ^ p.x) ^ p.y) * 3u;
  vec3 u = vec3(unit(lowbias32(h)), unit(lowbias32(h + 1u)), unit(lowbias32(h + 2u)));
  return vec4(floor(255.0 * v + u) / 255.0, 1.0);
}`;

function compile(gl, type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) {
    throw new Error(`shader: ${gl.getShaderInfoLog(shader)}`);
  }
  return shader;
}

/** A linked program of VERTEX and `fragment`. */
export function program(gl, fragment) {
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, VERTEX));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fragment));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`program: ${gl.getProgramInfoLog(p)}`);
  return p;
}

/** A 2-D texture sampled texel by texel (texelFetch: NEAREST, no mipmaps needed). */
export function texture(gl) {
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  for (const [k, v] of [
    [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE],
    [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE],
    [gl.TEXTURE_MIN_FILTER, gl.NEAREST],
    [gl.TEXTURE_MAG_FILTER, gl.NEAREST],
  ]) gl.texParameteri(gl.TEXTURE_2D, k, v);
  return t;
}
