// Heads-up display: rates, latency, the model's state at the gaze, connection status, and a
// ring where the server put the gaze (one per pane in split view). Text is rebuilt a few times
// a second, not every draw. Also the split view's divider and pane labels.

import { ENCODING_NAMES } from './protocol.js';

/** Events per second over the last `windowMs`, from a list of timestamps (ms). */
export class RateMeter {
  constructor(windowMs = 1000) {
    this.windowMs = windowMs;
    this.times = [];
  }
  tick(now) {
    this.times.push(now);
    this.prune(now);
  }
  prune(now) {
    const t = this.times;
    let i = 0;
    while (i < t.length && t[i] < now - this.windowMs) i++;
    if (i) t.splice(0, i);
  }
  rate(now) {
    this.prune(now);
    return (this.times.length * 1000) / this.windowMs;
  }
}

/** A ring of the last `size` samples with percentiles. */
export class Ring {
  constructor(size = 64) {
    this.size = size;
    this.values = [];
    this.total = 0; // values ever pushed, so a reader polling now and then can tell new ones
  }
  push(v) {
    this.total += 1;
    this.values.push(v);
    if (this.values.length > this.size) this.values.shift();
  }
  percentile(p) {
    if (!this.values.length) return NaN;
    const s = [...this.values].sort((a, b) => a - b);
    return s[Math.min(s.length - 1, Math.floor((p / 100) * s.length))];
  }
}

const fmt = (v, digits = 1) => (Number.isFinite(v) ? v.toFixed(digits) : '–');

/** "jacobs + stochastic" for a {afterimage, acuity} from the state message. */
export const modelLabel = (m) => (m ? `${m.afterimage} + ${m.acuity}` : '–');

/** Where the right pane starts, as a fraction of the frame width (0: no split). */
const splitAt = (h) => (h?.split ? Math.floor(h.width / 2) / h.width : 0);

/** 10^A as a readable luminance: 100, 3.2e5, 0.01. */
function luminance(a) {
  if (!Number.isFinite(a)) return '–';
  const y = 10 ** a;
  return y >= 1e4 || y < 1e-2 ? y.toExponential(1) : String(Number(y.toPrecision(3)));
}

/** A small plot of the eye's adaptation A (red, log10 cd/m², its own range) and ρ (blue,
 * 0 to 1 between the dashed lines: scotopic below, photopic above) at the gaze over the
 * last `seconds` of simulation time, from the frame headers. */
export class Plot {
  constructor(canvas, seconds = 10) {
    this.canvas = canvas;
    this.seconds = seconds;
    this.samples = []; // [time, A, rho]
    this.drawnSpan = 0; // seconds of simulation time the last draw covered (tests wait on it)
  }

  record(header) {
    const s = this.samples;
    if (s.length && header.time <= s[s.length - 1][0]) s.length = 0; // a new session's clock
    s.push([header.time, header.adaptation, header.rho]);
    while (s.length && s[0][0] < header.time - this.seconds) s.shift();
  }

  draw() {
    const c = this.canvas;
    const ctx = c.getContext('2d');
    ctx.clearRect(0, 0, c.width, c.height);
    const s = this.samples;
    this.drawnSpan = 0;
    if (s.length < 2) return;
    const t1 = s[s.length - 1][0];
    this.drawnSpan = t1 - s[0][0];
    const x = (t) => c.width * (1 - (t1 - t) / this.seconds);
    const as = s.map((v) => v[1]);
    const lo = Math.min(...as) - 0.1;
    const hi = Math.max(...as) + 0.1;
    const h = c.height - 12;
    const line = (values, toY, colour) => {
      ctx.strokeStyle = colour;
      ctx.beginPath();
      values.forEach((v, i) => ctx[i ? 'lineTo' : 'moveTo'](x(s[i][0]), toY(v)));
      ctx.stroke();
    };
    const rhoY = (r) => h - (Math.min(Math.max(r, -0.25), 1.25) + 0.25) / 1.5 * h;
    ctx.setLineDash([2, 3]);
    ctx.strokeStyle = '#555';
    for (const r of [0, 1]) {
      ctx.beginPath();
      ctx.moveTo(0, rhoY(r));
      ctx.lineTo(c.width, rhoY(r));
      ctx.stroke();
    }
    ctx.setLineDash([]);
    line(as, (a) => h - ((a - lo) / (hi - lo)) * h, '#ff6060');
    line(s.map((v) => v[2]), rhoY, '#60a0ff');
    ctx.fillStyle = '#aaa';
    ctx.font = '10px ui-monospace, monospace';
    ctx.fillText(`A ${lo.toFixed(1)}…${hi.toFixed(1)} · ρ · last ${this.seconds} s`, 0, c.height - 1);
  }
}

export class Hud {
  /** `element`: the HUD (its text and plot); `markers`: gaze rings for the frame (or left
   * pane) and the right pane. */
  constructor(element, markers) {
    this.element = element;
    this.text = element.querySelector('.text');
    this.plot = new Plot(element.querySelector('.plot'));
    this.markers = markers;
    this.visible = true;
  }

  toggle(visible = !this.visible) {
    this.visible = visible;
    this.element.hidden = !visible;
    if (!visible) for (const m of this.markers) m.hidden = true;
  }

  /** Rebuild the text. `info`: see main.js's hudInfo(). */
  update(info) {
    if (!this.visible) return;
    const h = info.header;
    const lines = [];
    lines.push(`gazehdr · ${info.connection}${info.session ? ` · session ${info.session}` : ''}`);
    lines.push(
      `frames ${fmt(info.frameRate)} fps · draws ${fmt(info.drawRate)} fps · dropped ${h ? h.dropped : '–'}`,
    );
    lines.push(
      `latency p50 ${fmt(info.latencyP50, 0)} ms · p95 ${fmt(info.latencyP95, 0)} ms · ` +
        `server ${h ? fmt(h.server_ms) : '–'} ms`,
    );
    if (h) {
      const where = h.split ? ' (left pane)' : '';
      lines.push(
        `A = ${fmt(h.adaptation, 2)} (${luminance(h.adaptation)} cd/m²) · ρ = ${fmt(h.rho, 2)}${where}`,
      );
      lines.push(
        `frame ${h.width}×${h.height} ${ENCODING_NAMES[h.encoding] ?? h.encoding} · ` +
          `#${h.frame} · t = ${fmt(h.time, 2)} s`,
      );
      lines.push(
        `gaze ${fmt(h.gaze_x, 3)}, ${fmt(h.gaze_y, 3)} (${h.tracker_gaze ? 'tracker' : 'pointer'}) · ` +
          `eyes ${h.eyes_open ? 'open' : 'closed'}`,
      );
    } else {
      lines.push('no frame yet');
    }
    lines.push(
      (info.split
        ? `split · left ${modelLabel(info.model)} | right ${modelLabel(info.split)}`
        : `model ${modelLabel(info.model)}`) + ` · preset ${info.preset ?? '–'}`,
    );
    lines.push(`scene ${info.scene ?? '–'} · source ${info.gazeSource ?? '–'}`);
    lines.push(`tracker ${info.tracker}`);
    this.text.textContent = lines.join('\n');
    this.plot.draw();
  }

  /** Place the gaze ring at the header's gaze (frame fractions) inside the drawn rectangle;
   * in split view the header has the left pane's gaze, and the right pane's ring is offset by
   * the pane width. */
  placeMarker(header, rect) {
    const shown = this.visible && header && Number.isFinite(header.gaze_x);
    const offsets = !shown ? [] : header.split ? [0, splitAt(header)] : [0];
    this.markers.forEach((marker, i) => {
      marker.hidden = i >= offsets.length;
      if (marker.hidden) return;
      const x = rect.x + (header.gaze_x + offsets[i]) * rect.width;
      const y = rect.y + header.gaze_y * rect.height;
      marker.style.transform = `translate(${x}px, ${y}px)`;
    });
  }
}

/** The split view's divider and one label per pane, over the drawn frame; shown while the
 * frames are split (header flag), labelled from the state (which model is in which pane). */
export class SplitOverlay {
  constructor(root) {
    this.root = root;
    this.divider = root.querySelector('.divider');
    this.labels = [...root.querySelectorAll('.pane-label')];
  }

  place(header, rect, model, split) {
    const at = splitAt(header);
    this.root.hidden = !at;
    if (!at) return;
    const x = rect.x + at * rect.width;
    Object.assign(this.divider.style, { left: `${x}px`, top: `${rect.y}px`, height: `${rect.height}px` });
    const [left, right] = this.labels;
    left.textContent = modelLabel(model);
    right.textContent = modelLabel(split);
    const bottom = `${window.innerHeight - rect.y - rect.height + 6}px`;
    Object.assign(left.style, { left: `${rect.x + 6}px`, bottom });
    Object.assign(right.style, { left: `${x + 6}px`, bottom });
  }
}
