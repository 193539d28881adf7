// Inspection, tev-like, in cd/m²: the readout under the pointer (the scene's radiance, the
// display value, the eye's state there), a false-colour view of log luminance with its
// legend, and a histogram of log luminance with the eye's adaptation and the 100 cd/m² floor
// marked. Everything comes from the server's scene map (docs/protocol.md), the last frame and
// its header: nothing here is estimated.

import { ENCODING, ENCODING_NAMES, decodeSceneMap, halfToFloat } from './protocol.js';

/** log10 cd/m² spanned by the false colour and the histogram: starlight to a bright sky. The
 * range is absolute, so a change of the scene's scale moves both. */
export const LOG_RANGE = Object.freeze([-3, 7]);
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

/** The false colour of t in [0, 1] as [r, g, b] bytes. */
export function colourOf(t) {
  const x = Math.min(Math.max(t, 0), 1) * (STOPS.length - 1);
  const i = Math.min(Math.floor(x), STOPS.length - 2);
  const f = x - i;
  return STOPS[i].map((a, c) => Math.round(a + (STOPS[i + 1][c] - a) * f));
}

const sci = (v) => (!Number.isFinite(v) ? '–' : v === 0 ? '0' : Math.abs(v) >= 1e4 || Math.abs(v) < 1e-2 ? v.toExponential(3) : String(Number(v.toPrecision(4))));
const toUnit = (logY) => (logY - LOG_RANGE[0]) / (LOG_RANGE[1] - LOG_RANGE[0]);

/** The display value `v` of frame pixel (x, y) from a frame message; null where the message
 * holds none: `warp` (composed in the shader, at the newest gaze), `av1` (a stream's packet). */
function displayValue(payload, header, x, y) {
  if (header.encoding === ENCODING.WARP || header.encoding === ENCODING.AV1) return null;
  const i = y * header.width + x;
  if (header.encoding === ENCODING.F16) {
    const px = new Uint16Array(payload, header.header_bytes + i * 6, 3);
    return [...px].map(halfToFloat);
  }
  const word = new Uint32Array(payload, header.header_bytes + i * 4, 1)[0];
  return [0, 10, 20].map((s) => ((word >>> s) & 1023) / 1023);
}

export class Inspector {
  /** `root`: the inspector box (readout, histogram, legend); `overlay`: the false-colour
   * canvas over the frame. */
  constructor(root, overlay) {
    this.root = root;
    this.overlay = overlay;
    this.text = root.querySelector('.readout');
    this.histogram = root.querySelector('canvas.histogram');
    this.legend = root.querySelector('.legend');
    this.map = null;
    this.logY = null;
    this.counts = null;
    this.image = null; // the false colour of one pane, a canvas
    this.last = null; // the last readout, for tests
    this.visible = false;
    this.falseColour = false;
    root.hidden = true;
    overlay.hidden = true;
    this.drawLegend();
  }

  toggle(visible = !this.visible) {
    this.visible = visible;
    this.root.hidden = !visible;
  }

  setFalseColour(on) {
    this.falseColour = on;
    this.overlay.hidden = !on;
    this.legend.hidden = !on;
  }

  /** A new scene map: luminance, histogram and false colour follow it. */
  setMap(buffer, weights = REC709_Y) {
    const map = decodeSceneMap(buffer);
    const n = map.width * map.height;
    const logY = new Float32Array(n);
    const counts = new Uint32Array(BINS);
    const image = document.createElement('canvas');
    [image.width, image.height] = [map.width, map.height];
    const ctx = image.getContext('2d');
    const pixels = ctx.createImageData(map.width, map.height);
    for (let i = 0; i < n; i++) {
      const r = map.radiance;
      const y = weights[0] * r[3 * i] + weights[1] * r[3 * i + 1] + weights[2] * r[3 * i + 2];
      const l = Math.log10(Math.max(y, 1e-12));
      logY[i] = l;
      const t = toUnit(l);
      counts[Math.min(BINS - 1, Math.max(0, Math.floor(t * BINS)))] += y > 0 ? 1 : 0;
      const [cr, cg, cb] = y > 0 ? colourOf(t) : [0, 0, 0];
      pixels.data.set([cr, cg, cb, 255], 4 * i);
    }
    ctx.putImageData(pixels, 0, 0);
    Object.assign(this, { map, logY, counts, image });
  }

  /**
   * What is under frame fraction (fx, fy): the scene pixel (in split view, the pane's: both
   * panes show the same scene), its radiance, luminance, display value and the eye's state.
   * Null off the frame or before a map.
   */
  readout(fx, fy, header, payload, weights = REC709_Y) {
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
    return {
      x, y, pane: header.split ? (right ? 'right' : 'left') : null, rgb, Y,
      log10Y: Math.log10(Y), display: displayValue(payload, header, fxPx, y),
      encoding: ENCODING_NAMES[header.encoding],
      rho: m.rho[i], adaptation: header.adaptation,
    }; // prettier-ignore
  }

  /** Refresh the readout text and the histogram's adaptation marker. */
  update(fx, fy, header, payload, state) {
    if (!this.visible) return;
    const weights = state.params?.w_P ?? REC709_Y;
    const r = this.readout(fx, fy, header, payload, weights);
    this.last = r;
    this.drawHistogram(header?.adaptation, state.params?.A_min ?? 2);
    const info = state.scene_info;
    const lines = [
      info ? `${state.scene} · ${sci(info.scale)} cd/m² per unit (${info.scale_source})` : '',
    ];
    if (!r) {
      lines.push(this.map ? 'point at the picture' : 'no scene map yet');
    } else {
      const where = r.pane ? ` (${r.pane} pane)` : '';
      lines.push(
        `pixel ${r.x}, ${r.y}${where}`,
        `RGB  ${r.rgb.map(sci).join('  ')} cd/m²`,
        `Y    ${sci(r.Y)} cd/m² · log10 ${r.log10Y.toFixed(3)}`,
        r.display
          ? `v    ${r.display.map((v) => v.toFixed(4)).join('  ')}`
          : `v    – (${r.encoding} frames: not read)`,
        `eye  A = ${r.adaptation.toFixed(2)} (${sci(10 ** r.adaptation)} cd/m²) · ρ here ${r.rho.toFixed(2)}`,
      );
    }
    this.text.textContent = lines.join('\n');
  }

  drawHistogram(adaptation, floor) {
    const c = this.histogram;
    const ctx = c.getContext('2d');
    ctx.clearRect(0, 0, c.width, c.height);
    const plotH = c.height - 14;
    if (this.counts) {
      const top = Math.max(...this.counts) || 1;
      const w = c.width / BINS;
      for (let b = 0; b < BINS; b++) {
        const h = (this.counts[b] / top) * plotH;
        ctx.fillStyle = `rgb(${colourOf((b + 0.5) / BINS).join(',')})`;
        ctx.fillRect(b * w, plotH - h, Math.ceil(w), h);
      }
    }
    const at = (l) => toUnit(l) * c.width;
    ctx.fillStyle = '#aaa';
    ctx.font = '10px ui-monospace, monospace';
    for (let d = LOG_RANGE[0]; d <= LOG_RANGE[1]; d += 2) ctx.fillText(`1e${d}`, Math.min(at(d), c.width - 24), c.height - 2);
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

  drawLegend() {
    const bar = this.legend.querySelector('canvas');
    const ctx = bar.getContext('2d');
    for (let x = 0; x < bar.width; x++) {
      ctx.fillStyle = `rgb(${colourOf(x / (bar.width - 1)).join(',')})`;
      ctx.fillRect(x, 0, 1, bar.height);
    }
    const labels = this.legend.querySelector('.labels');
    labels.replaceChildren(
      ...[LOG_RANGE[0], 0, 2, 4, LOG_RANGE[1]].map((d) => {
        const s = document.createElement('span');
        s.textContent = `10${d < 0 ? '⁻' : ''}${String(Math.abs(d)).replace(/\d/g, (c) => '⁰¹²³⁴⁵⁶⁷⁸⁹'[c])}`;
        s.style.left = `${toUnit(d) * 100}%`;
        return s;
      }),
    );
  }

  /** Draw the false colour over the frame rectangle (both panes in split view). */
  place(header, rect) {
    if (!this.falseColour) return;
    const o = this.overlay;
    Object.assign(o.style, { left: `${rect.x}px`, top: `${rect.y}px`, width: `${rect.width}px`, height: `${rect.height}px` });
    const [w, h] = [Math.round(rect.width), Math.round(rect.height)];
    if (o.width !== w || o.height !== h) [o.width, o.height] = [w, h];
    const ctx = o.getContext('2d');
    ctx.clearRect(0, 0, w, h);
    if (!this.image || !header) return;
    ctx.imageSmoothingEnabled = false;
    const panes = header.split ? 2 : 1;
    const paneW = (Math.floor(header.width / panes) / header.width) * w;
    for (let p = 0; p < panes; p++) ctx.drawImage(this.image, p * paneW, 0, paneW, h);
  }
}
