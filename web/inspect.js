// Inspection, tev-like, in cd/m²: the readout under the pointer (the file's value in its own
// units, the scene's radiance, the display value, the eye's state there), two views of the
// scene over the frame (the file's values at an exposure, as tev shows them; false colour of
// log luminance over a chosen range, with its legend), and a histogram of log luminance with
// the eye's adaptation and the 100 cd/m² floor marked. Everything comes from the server's
// scene map (docs/protocol.md), the last frame, its header and the state's scene_info: nothing
// here is estimated. Nothing here changes what the simulation shows or the server sends.

import { ENCODING, ENCODING_NAMES, decodeSceneMap, halfToFloat, isStream } from './protocol.js';

/** log10 cd/m² spanned by the histogram, and by the false colour unless a range is set:
 * starlight to a bright sky. The range is absolute, so a change of the scene's scale moves
 * both. */
export const LOG_RANGE = Object.freeze([-3, 7]);
/** Exposure, stops: its bounds and a key's step. */
export const EXPOSURE_MAX = 30;
export const EXPOSURE_STEP = 0.5;
const BINS = 100;
const REC709_Y = [0.2126, 0.7152, 0.0722];
// Viridis at five stops (dark blue, blue, teal, green, yellow), joined linearly.
const STOPS = [
  [68, 1, 84],
  [59, 82, 139],
  [33, 145, 140],
  [94, 201, 98],
  [253, 231, 37],
];
// Linear [0, 1] → sRGB bytes, a table fine enough to be within a byte of the formula.
const SRGB_N = 1 << 14;
const SRGB = Uint8ClampedArray.from({ length: SRGB_N }, (_, i) => {
  const x = i / (SRGB_N - 1);
  return Math.round(255 * (x <= 0.0031308 ? 12.92 * x : 1.055 * x ** (1 / 2.4) - 0.055));
});

/** The false colour of t in [0, 1] as [r, g, b] bytes. */
export function colourOf(t) {
  const x = Math.min(Math.max(t, 0), 1) * (STOPS.length - 1);
  const i = Math.min(Math.floor(x), STOPS.length - 2);
  const f = x - i;
  return STOPS[i].map((a, c) => Math.round(a + (STOPS[i + 1][c] - a) * f));
}

// ---- numbers: one format, 10⁻³ style, in the readout, the legend and the histogram ----------

const SUPERSCRIPT = { '-': '⁻', 0: '⁰', 1: '¹', 2: '²', 3: '³', 4: '⁴', 5: '⁵', 6: '⁶', 7: '⁷', 8: '⁸', 9: '⁹' };
const sup = (n) => [...String(n)].map((c) => SUPERSCRIPT[c] ?? c).join('');
const trim = (v, digits) => String(Number(v.toPrecision(digits)));

/** `v` as m·10ⁿ (1 ≤ m < 10, up to `digits` significant digits; "10ⁿ" when m is 1). */
export function powerOfTen(v, digits = 3) {
  if (v === 0) return '0';
  if (!Number.isFinite(v)) return '–';
  let n = Math.floor(Math.log10(Math.abs(v)));
  let m = Number((v / 10 ** n).toPrecision(digits));
  if (Math.abs(m) >= 10) [m, n] = [m / 10, n + 1];
  const mantissa = m === 1 ? '' : m === -1 ? '-' : `${trim(m, digits)}·`;
  return `${mantissa}10${sup(n)}`;
}

/** A value for the readout: plain between 0.01 and 10⁴, else m·10ⁿ; black is 0. */
export function formatValue(v, digits = 4) {
  if (v === 0) return '0';
  if (!Number.isFinite(v)) return '–';
  const a = Math.abs(v);
  return a >= 1e4 || a < 1e-2 ? powerOfTen(v, digits) : trim(v, digits);
}

/** A place on the log10 cd/m² axis as a label: 10ⁿ, or m·10ⁿ between decades. */
const decadeLabel = (l) => powerOfTen(10 ** l, 2);

const signed = (e) => `${e > 0 ? '+' : e < 0 ? '−' : '±'}${Math.abs(e).toFixed(1)}`;

/** Python's round(): halves to even (gazehdr.sim.layout.fit_to_frame uses it). */
function roundHalfEven(x) {
  const r = Math.round(x);
  return Math.abs(x % 1) === 0.5 && r % 2 !== 0 ? r - 1 : r;
}

/**
 * Where scene-map pixel (x, y) of a `mw`×`mh` pane lies in the scene's file of
 * `info.width`×`info.height` px, as gazehdr.sim.layout.fit_to_frame fits the image to the pane:
 * `own` (the image at its own size, bars or not: the map's pixel is the file's), `mean` (the image shrunk: the area mean of
 * file px [x0, x1) × [y0, y1)), `interpolated` (enlarged: between the file px around (x, y)
 * of the file), `bar` (the black bars around the image). Null for a scene with no file.
 */
export function filePixel(info, mw, mh, x, y) {
  const [w, h] = [info?.width, info?.height];
  if (!(w > 0 && h > 0)) return null;
  const s = Math.min(mw / w, mh / h);
  const [nw, nh] = [Math.max(1, roundHalfEven(w * s)), Math.max(1, roundHalfEven(h * s))];
  const [u, v] = [x - Math.floor((mw - nw) / 2), y - Math.floor((mh - nh) / 2)];
  if (u < 0 || u >= nw || v < 0 || v >= nh) return { kind: 'bar' };
  if (nw === w && nh === h) return { kind: 'own', x: u, y: v, x0: u, x1: u + 1, y0: v, y1: v + 1 };
  const [sx, sy] = [w / nw, h / nh]; // file px per map px
  return {
    kind: nw < w || nh < h ? 'mean' : 'interpolated',
    x: (u + 0.5) * sx - 0.5, y: (v + 0.5) * sy - 0.5, // the map pixel's centre in the file
    x0: u * sx, x1: (u + 1) * sx, y0: v * sy, y1: (v + 1) * sy,
  }; // prettier-ignore
}

/** The display value `v` of frame pixel (x, y) from a frame message; null where the message
 * holds none: `warp` (composed in the shader, at the newest gaze), `h264`, `av1` (a stream's
 * packet). */
function displayValue(payload, header, x, y) {
  if (header.encoding === ENCODING.WARP || isStream(header.encoding)) return null;
  const i = y * header.width + x;
  if (header.encoding === ENCODING.F16) {
    const px = new Uint16Array(payload, header.header_bytes + i * 6, 3);
    return [...px].map(halfToFloat);
  }
  const word = new Uint32Array(payload, header.header_bytes + i * 4, 1)[0];
  return [0, 10, 20].map((s) => ((word >>> s) & 1023) / 1023);
}

export class Inspector {
  /** `root`: the inspector box (readout, histogram, legend); `overlay`: the canvas over the
   * frame where the scene view or the false colour is drawn. */
  constructor(root, overlay) {
    this.root = root;
    this.overlay = overlay;
    this.text = root.querySelector('.readout');
    this.histogram = root.querySelector('canvas.histogram');
    this.legend = root.querySelector('.legend');
    // The histogram and the legend in a column beside the readout (under it where the
    // window is too narrow for both).
    const charts = document.createElement('div');
    charts.className = 'charts';
    charts.append(this.histogram, this.legend);
    root.append(charts);
    this.map = null;
    this.Y = null; // luminance of the map's pixels, cd/m²
    this.counts = null;
    this.images = { false: null, scene: null }; // the current view of one pane, a canvas each
    this.last = null; // the last readout, for tests
    this.drawn = null; // what the overlay shows now: {mode, exposure, range, scale, seq}, for tests
    this.axisLabels = []; // the histogram's labels as drawn: {text, x, width}, for tests
    this.visible = false;
    // What the overlay shows: 'off' (the simulation only), 'scene' (the file's values ×
    // 2^exposure, sRGB, as tev shows them) or 'false' (false colour over `range`).
    this.mode = 'off';
    this.exposure = 0; // stops
    this.range = [...LOG_RANGE]; // log10 cd/m² of the false colour's ends
    this.scale = 1; // cd/m² per file unit (state.scene_info.scale)
    this.zoom = 1; // main.js's, shown in the readout
    root.hidden = true;
    overlay.hidden = true;
    this.legend.hidden = true;
    this.drawLegend();
  }

  get falseColour() {
    return this.mode === 'false';
  }

  get sceneView() {
    return this.mode === 'scene';
  }

  toggle(visible = !this.visible) {
    this.visible = visible;
    this.root.hidden = !visible;
  }

  /** The overlay's view: 'off', 'scene' or 'false' (one at a time). */
  setMode(mode) {
    this.mode = mode;
    this.overlay.hidden = mode === 'off';
    this.legend.hidden = mode !== 'false';
  }

  setFalseColour(on) {
    if (on) this.setMode('false');
    else if (this.mode === 'false') this.setMode('off');
  }

  setSceneView(on) {
    if (on) this.setMode('scene');
    else if (this.mode === 'scene') this.setMode('off');
  }

  /** The scene view's exposure, stops (rounded to 0.01, within ±EXPOSURE_MAX). */
  setExposure(stops) {
    if (!Number.isFinite(stops)) return;
    const e = Math.round(Math.min(Math.max(stops, -EXPOSURE_MAX), EXPOSURE_MAX) * 100) / 100;
    if (e === this.exposure) return;
    this.exposure = e;
    this.images.scene = null;
  }

  /** The exposure that puts the brightest 1% of the scene's luminance at white. */
  fitExposure() {
    if (!this.Y) return this.exposure;
    const lit = this.Y.filter((y) => y > 0).sort();
    if (!lit.length) return this.exposure;
    const p99 = lit[Math.min(lit.length - 1, Math.floor(0.99 * lit.length))] / this.scale;
    return Math.round(-Math.log2(p99) * 2) / 2;
  }

  /** The false colour's range [lo, hi] in log10 cd/m² (lo < hi); null: LOG_RANGE. False if
   * refused. */
  setRange(range) {
    const [lo, hi] = range ?? LOG_RANGE;
    if (!(Number.isFinite(lo) && Number.isFinite(hi) && lo < hi)) return false;
    this.range = [lo, hi];
    this.images.false = null;
    this.drawLegend();
    return true;
  }

  /** The range from the darkest to the brightest lit pixel of the scene, in tenths. */
  fitRange() {
    if (!this.Y) return this.range;
    let [lo, hi] = [Infinity, -Infinity];
    for (const y of this.Y) {
      if (y <= 0) continue;
      lo = Math.min(lo, y);
      hi = Math.max(hi, y);
    }
    if (!(lo <= hi)) return this.range;
    lo = Math.floor(Math.log10(lo) * 10) / 10;
    hi = Math.ceil(Math.log10(hi) * 10) / 10;
    return hi > lo ? [lo, hi] : [lo - 0.5, lo + 0.5];
  }

  /** A new scene map: luminance, histogram and the views follow it. */
  setMap(buffer, weights = REC709_Y) {
    const map = decodeSceneMap(buffer);
    const n = map.width * map.height;
    const r = map.radiance;
    const Y = new Float32Array(n);
    const counts = new Uint32Array(BINS);
    const [lo, hi] = LOG_RANGE;
    for (let i = 0; i < n; i++) {
      const y = weights[0] * r[3 * i] + weights[1] * r[3 * i + 1] + weights[2] * r[3 * i + 2];
      Y[i] = y;
      if (y > 0) counts[Math.min(BINS - 1, Math.max(0, Math.floor(((Math.log10(y) - lo) / (hi - lo)) * BINS)))] += 1;
    }
    Object.assign(this, { map, Y, counts, images: { false: null, scene: null } });
  }

  /** A canvas of the map's size: `paint(i)` gives pixel i's [r, g, b] bytes. */
  paint(fill) {
    const m = this.map;
    const image = document.createElement('canvas');
    [image.width, image.height] = [m.width, m.height];
    const ctx = image.getContext('2d');
    const pixels = ctx.createImageData(m.width, m.height);
    fill(pixels.data, m.width * m.height);
    ctx.putImageData(pixels, 0, 0);
    return image;
  }

  /** The false colour of the map: log10 luminance over `range`, clamped at its ends; black
   * (0 cd/m²) stays black. */
  falseImage() {
    const [lo, hi] = this.range;
    return this.paint((data, n) => {
      for (let i = 0; i < n; i++) {
        const y = this.Y[i];
        data.set(y > 0 ? colourOf((Math.log10(y) - lo) / (hi - lo)) : [0, 0, 0], 4 * i);
        data[4 * i + 3] = 255;
      }
    });
  }

  /** The scene as tev shows its file: each channel's value in file units (radiance ÷ scale)
   * × 2^exposure, clipped to [0, 1], sRGB-encoded. */
  sceneImage() {
    const r = this.map.radiance;
    const gain = (2 ** this.exposure / this.scale) * (SRGB_N - 1);
    return this.paint((data, n) => {
      for (let i = 0; i < n; i++) {
        for (let c = 0; c < 3; c++) data[4 * i + c] = SRGB[Math.round(Math.min(Math.max(r[3 * i + c] * gain, 0), SRGB_N - 1))];
        data[4 * i + 3] = 255;
      }
    });
  }

  /**
   * What is under frame fraction (fx, fy): the scene pixel (in split view, the pane's: both
   * panes show the same scene), its radiance, luminance, display value, the eye's state, and
   * where it lies in the scene's file with its value in file units (`info`: the state's
   * scene_info). Null off the frame or before a map.
   */
  readout(fx, fy, header, payload, weights = REC709_Y, info = null) {
    const m = this.map;
    if (!m || !header || !(fx >= 0 && fx < 1 && fy >= 0 && fy < 1)) return null;
    const fxPx = Math.floor(fx * header.width);
    const y = Math.floor(fy * header.height);
    const paneWidth = header.split ? Math.floor(header.width / 2) : header.width;
    const right = header.split && fxPx >= paneWidth;
    const x = right ? fxPx - paneWidth : fxPx;
    if (x >= m.width || y >= m.height) return null; // a frame of another size: a new map comes
    const i = y * m.width + x;
    const rgb = [0, 1, 2].map((c) => m.radiance[3 * i + c]);
    const Y = rgb.reduce((s, v, c) => s + v * weights[c], 0);
    const file = filePixel(info, m.width, m.height, x, y);
    const scale = info?.scale > 0 ? info.scale : null;
    return {
      x, y, pane: header.split ? (right ? 'right' : 'left') : null, rgb, Y,
      log10Y: Y > 0 ? Math.log10(Y) : null, display: displayValue(payload, header, fxPx, y),
      encoding: ENCODING_NAMES[header.encoding],
      rho: m.rho[i], adaptation: header.adaptation,
      file, scale, units: file && scale ? rgb.map((v) => v / scale) : null,
    }; // prettier-ignore
  }

  /** The scene's description (the state's scene_info): its scale, cd/m² per file unit. */
  setScene(info) {
    if (info?.scale > 0 && info.scale !== this.scale) {
      this.scale = info.scale;
      this.images.scene = null;
    }
  }

  /** Refresh the readout text and the histogram's adaptation marker. */
  update(fx, fy, header, payload, state) {
    const info = state.scene_info;
    this.setScene(info);
    if (!this.visible) return;
    const weights = state.params?.w_P ?? REC709_Y;
    const r = this.readout(fx, fy, header, payload, weights, info);
    this.last = r;
    this.drawHistogram(header?.adaptation, state.params?.A_min ?? 2);
    const lines = [
      info ? `${state.scene} · ${formatValue(info.scale)} cd/m² per unit (${info.scale_source})` : '',
    ];
    if (!r) {
      lines.push(this.map ? 'point at the picture' : 'no scene map yet');
    } else {
      const values = (vs) => vs.map((v) => formatValue(v)).join('  ');
      lines.push(`pixel ${r.x}, ${r.y} of the ${this.map.width}×${this.map.height} ${r.pane ? `${r.pane} pane` : 'frame'}`);
      lines.push(...this.fileLines(r, info, values));
      lines.push(
        `scene RGB  ${values(r.rgb)} cd/m²`,
        r.Y > 0 ? `      Y    ${formatValue(r.Y)} cd/m² · log10 ${r.log10Y.toFixed(3)}` : '      Y    0 cd/m² (black)',
        r.display
          ? `shown v    ${r.display.map((v) => v.toFixed(4)).join('  ')} (${r.encoding} frame)`
          : `shown v    – (${r.encoding} frames: not read)`,
        `eye   A = ${r.adaptation.toFixed(2)} (${formatValue(10 ** r.adaptation)} cd/m²) · ρ here ${r.rho.toFixed(2)}`,
      );
    }
    lines.push(this.viewLine());
    this.text.textContent = lines.join('\n');
  }

  /** The readout's lines on the file: where the pixel lies in it, its value in file units. */
  fileLines(r, info, values) {
    const f = r.file;
    if (!f) return ['file  – (none: a scene drawn in cd/m²)'];
    const size = `${info.width}×${info.height}`;
    if (f.kind === 'bar') return [`file  – (the bars around its ${size}: 0)`];
    let where;
    if (f.kind === 'own') where = `px ${f.x}, ${f.y} of ${size}: its own pixel`;
    else if (f.kind === 'mean') {
      const span = (a, b) => (Math.ceil(b) - Math.floor(a) > 1 ? `${Math.floor(a)}–${Math.ceil(b) - 1}` : `${Math.floor(a)}`);
      where = `mean of px ${span(f.x0, f.x1)}, ${span(f.y0, f.y1)} of ${size}`;
    } else where = `near px ${trim(f.x, 4)}, ${trim(f.y, 4)} of ${size}: interpolated`;
    return [`file  ${where}`, `      RGB  ${r.units ? values(r.units) : '–'} file units`];
  }

  /** The view's settings, as the readout's last line. */
  viewLine() {
    const zoom = `zoom ${trim(this.zoom, 3)}×`;
    const exposure = `exposure ${signed(this.exposure)} stops`;
    if (this.mode === 'scene') return `view  scene view · ${exposure} · ${zoom}`;
    if (this.mode === 'false') return `view  false colour ${decadeLabel(this.range[0])}…${decadeLabel(this.range[1])} cd/m² · ${zoom}`;
    return `view  simulation · ${zoom} · ${exposure} (S)`;
  }

  drawHistogram(adaptation, floor) {
    const c = this.histogram;
    const ctx = c.getContext('2d');
    ctx.clearRect(0, 0, c.width, c.height);
    const plotH = c.height - 14;
    const [lo, hi] = LOG_RANGE;
    const [flo, fhi] = this.range;
    if (this.counts) {
      const top = Math.max(...this.counts) || 1;
      const w = c.width / BINS;
      for (let b = 0; b < BINS; b++) {
        const h = (this.counts[b] / top) * plotH;
        const l = lo + ((b + 0.5) / BINS) * (hi - lo);
        ctx.fillStyle = `rgb(${colourOf((l - flo) / (fhi - flo)).join(',')})`; // as the false colour
        ctx.fillRect(b * w, plotH - h, Math.ceil(w), h);
      }
    }
    const at = (l) => ((l - lo) / (hi - lo)) * c.width;
    ctx.fillStyle = '#aaa';
    ctx.font = '10px ui-monospace, monospace';
    this.axisLabels = [];
    for (let d = lo; d <= hi; d += 2) {
      const text = decadeLabel(d);
      const width = ctx.measureText(text).width;
      const x = Math.min(Math.max(at(d) - width / 2, 0), c.width - width); // inside the canvas
      ctx.fillText(text, x, c.height - 2);
      this.axisLabels.push({ text, x, width });
    }
    const mark = (l, colour, dash) => {
      if (!Number.isFinite(l)) return;
      ctx.strokeStyle = colour;
      ctx.setLineDash(dash);
      ctx.beginPath();
      ctx.moveTo(at(l), 0);
      ctx.lineTo(at(l), plotH);
      ctx.stroke();
    };
    mark(floor, '#bbb', [3, 3]); // the adaptation floor, 100 cd/m² in the paper
    mark(adaptation, '#ff5050', []);
    ctx.setLineDash([]);
  }

  /** The legend: the colour bar over `range`, its ends labelled "≤" and "≥" (the false colour
   * clamps there) and the decades between, every label inside the bar's width. */
  drawLegend() {
    const bar = this.legend.querySelector('canvas');
    const ctx = bar.getContext('2d');
    for (let x = 0; x < bar.width; x++) {
      ctx.fillStyle = `rgb(${colourOf(x / (bar.width - 1)).join(',')})`;
      ctx.fillRect(x, 0, 1, bar.height);
    }
    const [lo, hi] = this.range;
    const span = hi - lo;
    const step = Math.max(1, Math.ceil(span / 5));
    const marks = [[lo, `≤${decadeLabel(lo)}`, 'start']];
    for (let d = Math.ceil(lo / step) * step; d < hi; d += step) {
      if ((d - lo) / span > 0.15 && (hi - d) / span > 0.15) marks.push([d, decadeLabel(d), 'middle']);
    }
    marks.push([hi, `≥${decadeLabel(hi)}`, 'end']);
    this.legend.querySelector('.labels').replaceChildren(
      ...marks.map(([d, text, anchor]) => {
        const s = document.createElement('span');
        s.textContent = text;
        s.className = anchor;
        s.style.left = `${((d - lo) / span) * 100}%`;
        return s;
      }),
    );
    this.legend.querySelector('.unit').textContent = 'false colour: luminance, cd/m² (black: 0)';
  }

  /** Draw the current view (scene or false colour) over the frame rectangle `rect` (CSS px
   * from the canvas's corner `box`; both panes in split view), nearest pixel: zoomed, the
   * scene map's pixels are blocks, as the frame's are. */
  place(header, rect, box) {
    if (this.mode === 'off') return;
    const o = this.overlay;
    const [w, h] = [Math.max(1, Math.round(box.width)), Math.max(1, Math.round(box.height))];
    Object.assign(o.style, { left: `${box.left}px`, top: `${box.top}px`, width: `${w}px`, height: `${h}px` });
    if (o.width !== w || o.height !== h) [o.width, o.height] = [w, h];
    const ctx = o.getContext('2d');
    ctx.clearRect(0, 0, w, h);
    if (!this.map || !header) return;
    const image = (this.images[this.mode] ??= this.mode === 'scene' ? this.sceneImage() : this.falseImage());
    ctx.imageSmoothingEnabled = false;
    const panes = header.split ? 2 : 1;
    const paneW = (Math.floor(header.width / panes) / header.width) * rect.width;
    for (let p = 0; p < panes; p++) ctx.drawImage(image, rect.x + p * paneW, rect.y, paneW, rect.height);
    this.drawn = { mode: this.mode, exposure: this.exposure, range: [...this.range], scale: this.scale, seq: this.map.seq };
  }
}
