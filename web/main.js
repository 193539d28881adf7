// Wiring: the /ws/view connection (with reconnect), input (pointer = gaze, keys), and the draw
// loop. The server does the simulation; this page displays, dithers and reports.
// Past 600 lines because the connection, the inputs and the draw loop share the page's state
// (the session, the last frame, the gaze); what stands alone is in protocol.js, renderer.js,
// video.js, hud.js, inspect.js and panel.js.

import { binaryKind, decodeFrame, isStream, messages, parseText } from './protocol.js';
import { Renderer } from './renderer.js';
import { CODECS, VideoStream, unsupported } from './video.js';
import { Hud, RateMeter, Ring, SplitOverlay } from './hud.js';
import { EXPOSURE_STEP, Inspector } from './inspect.js';
import { Panel } from './panel.js';

const BACKOFF_MIN_MS = 500;
const BACKOFF_MAX_MS = 8000;
const VIEWPORT_DEBOUNCE_MS = 200;
const HUD_INTERVAL_MS = 250;
const SEQ_RING = 512; // send times kept for latency; far more than frames in flight

const canvas = document.getElementById('view');
const hud = new Hud(document.getElementById('hud'), [
  document.getElementById('marker'),
  document.getElementById('marker-right'),
]);
const splitOverlay = new SplitOverlay(document.getElementById('split-overlay'));
const inspector = new Inspector(document.getElementById('inspector'), document.getElementById('falsecolour'));
const toasts = document.getElementById('toasts');
const statusLine = document.getElementById('status');

function toast(text, ms = 4000) {
  const t = document.createElement('div');
  t.className = 'toast';
  t.textContent = text;
  toasts.append(t);
  setTimeout(() => t.remove(), ms);
}

let renderer;
try {
  renderer = new Renderer(canvas);
} catch (err) {
  document.getElementById('fatal').textContent = `${err.message}: gazehdr needs WebGL2.`;
  throw err;
}

const stats = {
  frames: new RateMeter(),
  draws: new RateMeter(),
  latency: new Ring(64),
  received: 0, // frames
  errors: 0,
  gazeSent: 0, // seq of the last gaze sent
  connects: 0, // sockets opened, reconnects included
  keyRequests: 0, // h264, av1: keyframes asked for after the stream broke
};
const state = {}; // the last hello/state from the server
// Late gaze warp (warp.js): afterimages placed at the newest pointer at every display refresh.
// Off unless asked for: the panel's box, or ?warp=1 (tests and comparisons).
let warpOn = new URLSearchParams(location.search).get('warp') === '1';
// The newest gaze of the session's tracker, which the server forwards (`gaze` notes) while the
// warp is on: where the warp places the afterimages when a tracker, not the pointer, is the gaze.
let trackerGaze = null;
// The gaze daemons' trackers this server has heard of, by name (state and `tracker` notes):
// a session follows one of them by choosing gaze source `remote:NAME`.
const trackers = new Map();

// ---- connection -------------------------------------------------------------------------

class Connection {
  constructor() {
    this.ws = null;
    this.status = 'connecting';
    this.session = null;
    this.attempt = 0;
    this.retryAt = 0;
    this.timer = null;
    this.helloSeen = false;
    this.opened = false;
  }

  url() {
    const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
    const query = this.session ? `?session=${encodeURIComponent(this.session)}` : '';
    return `${scheme}://${location.host}/ws/view${query}`;
  }

  open() {
    clearTimeout(this.timer);
    this.status = this.attempt ? 'reconnecting' : 'connecting';
    this.helloSeen = false;
    this.opened = false;
    const ws = new WebSocket(this.url());
    ws.binaryType = 'arraybuffer';
    this.openedAt = performance.now();
    ws.onopen = () => {
      this.status = 'open';
      this.opened = true;
      stats.connects += 1;
      trackerGaze = null; // another session, maybe: its tracker's gaze comes anew
      sendViewport();
      this.send(messages.sceneMaps(wantMaps())); // for the inspector and the false colour
      if (warpOn) this.send(messages.warp(true));
      chooseEncoding();
      if (eyesClosed) this.send(messages.eyes(false));
    };
    ws.onmessage = (ev) => (typeof ev.data === 'string' ? onText(ev.data) : onBinary(ev.data));
    ws.onclose = (ev) => this.closed(ws, ev);
    this.ws = ws;
  }

  closed(ws, ev) {
    if (ws !== this.ws) return;
    this.ws = null;
    // Refusals of gazehdr.security (docs/security.md): 4000 + the HTTP status, with a reason.
    // Those that no retry can mend stop the page, saying how to get in.
    const refusal = REFUSALS[ev.code];
    if (refusal) {
      this.status = 'refused';
      this.refusal = refusal(ev.reason);
      toast(this.refusal, 15000);
      return;
    }
    if (ev.code === 4429) toast(`too many failed authentications (4429): ${ev.reason}`);
    // Opened but closed before hello: the server refused the session (it restarted and no
    // longer knows it). Start a fresh one next time. A failed connect keeps it: a blip.
    if (this.opened && !this.helloSeen) this.session = null;
    const delay = Math.min(BACKOFF_MAX_MS, BACKOFF_MIN_MS * 2 ** this.attempt);
    this.attempt += 1;
    this.status = 'reconnecting';
    this.retryAt = performance.now() + delay;
    this.timer = setTimeout(() => this.open(), delay);
  }

  hello(msg) {
    this.helloSeen = true;
    this.attempt = 0; // back-off restarts once a connection really works
    if (msg.session != null) this.session = String(msg.session);
  }

  send(msg) {
    if (this.ws?.readyState !== WebSocket.OPEN) return false;
    this.ws.send(JSON.stringify(msg));
    return true;
  }

  /** Drop the socket as if the network had (for debugging and tests). */
  drop() {
    this.ws?.close();
  }

  describe(now) {
    if (this.status !== 'reconnecting' || !this.timer) return this.status;
    const s = Math.max(0, (this.retryAt - now) / 1000);
    return this.ws ? 'reconnecting' : `reconnecting in ${s.toFixed(1)} s`;
  }
}

/** Refusals that retrying does not mend, and what to do instead (the page stops retrying). */
const REFUSALS = {
  4401: () =>
    'not authorized (4401): this browser has no credential for this server. Open the address ' +
    '`gazehdr serve` printed for other machines, ending in /?token=…, once; then reload.',
  4403: () => 'the server refused this page’s origin (4403): open the viewer from the server’s own address.',
  4421: (reason) => `the server does not answer to this name (4421): ${reason}`,
};

const conn = new Connection();
const send = (msg) => conn.send(msg);
/** Scene maps (10 bytes a pixel: 20 MB at 1080p) feed the inspector, the false colour and the
 * scene view: on a raw connection always; on a stream (h264, av1), a remote viewer's, only
 * while one of them is shown. */
function wantMaps() {
  return !(wantedEncoding in CODECS) || inspector.visible || inspector.mode !== 'off';
}

/** The inspector's settings as the panel shows them. */
function showInspector() {
  panel.showView(inspector.falseColour, inspector.visible);
  panel.showInspector({
    sceneView: inspector.sceneView, exposure: inspector.exposure, range: inspector.range,
    zoom: renderer.view.scale,
  }); // prettier-ignore
}

const view = {
  falseColour(on = !inspector.falseColour) {
    inspector.setFalseColour(on);
    send(messages.sceneMaps(wantMaps()));
    showInspector();
  },
  /** The scene as tev shows its file (values × 2^exposure), over the simulation. */
  sceneView(on = !inspector.sceneView) {
    inspector.setSceneView(on);
    send(messages.sceneMaps(wantMaps()));
    showInspector();
  },
  inspector(on = !inspector.visible) {
    inspector.toggle(on);
    if (!on) zoom.reset(); // the zoom is the inspector's: closing it shows the whole frame
    send(messages.sceneMaps(wantMaps()));
    showInspector();
  },
  /** The scene view's exposure in stops; 'fit': the brightest 1% at white. */
  exposure(stops) {
    inspector.setExposure(stops === 'fit' ? inspector.fitExposure() : stops);
    showInspector();
  },
  /** The false colour's range [lo, hi] (log10 cd/m²); null: the default; 'fit': the scene's.
   * False if refused. */
  falseRange(range) {
    const ok = inspector.setRange(range === 'fit' ? inspector.fitRange() : range);
    showInspector();
    return ok;
  },
  zoomReset() {
    zoom.reset();
  },
  /** The late gaze warp on or off (the server switches this viewer's frames). */
  warp(on = !warpOn) {
    warpOn = Boolean(on);
    if (!warpOn) trackerGaze = null;
    send(messages.warp(warpOn));
    panel.showWarp(warpOn);
  },
};
const panel = new Panel(document.getElementById('panel'), send, toast, view);
panel.showWarp(warpOn);
showInspector();

/** What the page waits for, until the first frame: the first frame of a new session takes
 * the server a moment (its OpenCL kernels are built on first use). */
function showStatus(now) {
  let text = '';
  if (!lastHeader) {
    const s = ((now - (conn.openedAt ?? now)) / 1000).toFixed(1);
    if (conn.status === 'refused') text = conn.refusal;
    else if (!conn.opened) text = `connecting to the server… ${conn.describe(now)}`;
    else if (!conn.helloSeen) text = `the server is preparing the simulation (it builds its kernels on first use)… ${s} s`;
    else text = `waiting for the first frame… ${s} s`;
  }
  if (statusLine.textContent !== text) statusLine.textContent = text;
}

// ---- messages from the server -----------------------------------------------------------

let lastHeader = null;
let pending = null; // newest decoded frame not yet uploaded: upload only what gets drawn
let pendingPlanes = null; // the same for a stream: the newest decoded picture's planes

// ?encoding=h264 (or av1, f16, rgb10a2) asks the server for that encoding for this page; a
// stream only where this browser can decode it, else the page says why and keeps the raw frames.
const wantedEncoding = new URLSearchParams(location.search).get('encoding');
const video = new VideoStream(
  (planes) => {
    if (!pendingPlanes || planes.frame > pendingPlanes.frame) pendingPlanes = planes;
  },
  (why) => {
    stats.keyRequests += 1;
    console.warn(`${wantedEncoding} stream lost (${why}): asking for a keyframe`);
    send(messages.keyframe());
  },
);

async function chooseEncoding() {
  if (!wantedEncoding) return;
  video.keyed = false; // a new connection: its stream starts with a keyframe
  if (wantedEncoding in CODECS) {
    const why = await unsupported(wantedEncoding);
    if (why) {
      api.encodingRefused = why;
      toast(`no ${wantedEncoding} frames: ${why}; showing the server's raw frames`, 10000);
      return;
    }
  }
  send(messages.encoding(wantedEncoding));
}
let lastPayload = null;
const gazeSentAt = new Float64Array(SEQ_RING);
let gazeSeq = 0;
let latencySeq = 0; // newest seq already counted, so each gaze gives one latency sample

function onBinary(buffer) {
  if (binaryKind(buffer) !== 'scene') return onFrame(buffer);
  try {
    inspector.setMap(buffer, state.params?.w_P);
    api.sceneMap = buffer;
    api.sceneMaps += 1;
  } catch (err) {
    stats.errors += 1;
    console.warn('bad scene map:', err.message);
  }
}

function onFrame(buffer) {
  let frame;
  try {
    frame = decodeFrame(buffer);
  } catch (err) {
    stats.errors += 1;
    console.warn('bad frame:', err.message);
    return;
  }
  const now = performance.now();
  const h = frame.header;
  // Flow control: the server keeps at most two frames in flight to a page that acks, so a
  // busy page gets the newest frame next instead of a backlog in the socket buffers.
  send(messages.ack(h.frame));
  stats.frames.tick(now);
  stats.received += 1;
  if (h.gaze_seq > latencySeq && h.gaze_seq <= gazeSeq && gazeSeq - h.gaze_seq < SEQ_RING) {
    stats.latency.push(now - gazeSentAt[h.gaze_seq % SEQ_RING]);
    latencySeq = h.gaze_seq;
  }
  lastHeader = h;
  lastPayload = buffer;
  hud.plot.record(h);
  if (isStream(h.encoding)) video.decode(h, frame.packet);
  else pending = frame;
  api.lastHeader = h;
  api.lastPayload = buffer;
}

function onText(text) {
  const msg = parseText(text);
  if (!msg) return console.warn('bad message:', text.slice(0, 200));
  switch (msg.type) {
    case 'hello':
      conn.hello(msg);
    // falls through: hello carries the whole state
    case 'state': {
      const { type, ...rest } = msg;
      if (rest.gaze_source !== state.gaze_source) trackerGaze = null; // another tracker's, or none
      Object.assign(state, rest);
      inspector.setScene(state.scene_info);
      trackers.clear();
      for (const t of state.trackers ?? []) trackers.set(t.name, t);
      panel.update(state);
      break;
    }
    case 'error':
      stats.errors += 1;
      toast(`${msg.in ? `${msg.in}: ` : ''}${msg.message}`);
      break;
    case 'tracker': { // a daemon connected or left: its tracker can be followed by name
      const { type, ...t } = msg;
      trackers.set(t.name, t);
      const source = `remote:${t.name}`;
      if (state.gaze_sources && !state.gaze_sources.includes(source)) {
        state.gaze_sources = [...state.gaze_sources, source];
        panel.update(state);
      }
      break;
    }
    case 'gaze': // the tracker's newest gaze, forwarded for the warp (docs/protocol.md)
      if (Number.isFinite(msg.x) && Number.isFinite(msg.y)) {
        trackerGaze = { x: msg.x, y: msg.y, eyesOpen: msg.eyes_open, t: msg.t };
      }
      break;
    case 'scenes': // the scene list changed (an upload), sent to every session
      state.scenes = msg.scenes;
      panel.update(state);
      break;
    default:
      console.warn('unknown message type', msg.type);
  }
}

// ---- input ------------------------------------------------------------------------------

let pointer = null; // newest pointer position (client px), sent at most once per frame
let eyesClosed = false;

function sendViewport() {
  send(messages.viewport(canvas.clientWidth, canvas.clientHeight));
}

let viewportTimer = null;
window.addEventListener('resize', () => {
  clearTimeout(viewportTimer);
  viewportTimer = setTimeout(sendViewport, VIEWPORT_DEBOUNCE_MS);
});

let hover = null; // where the pointer is over the picture, for the inspector and the warp

window.addEventListener('pointermove', (ev) => {
  if (ev.target instanceof Element && ev.target.closest('#panel')) return; // using the panel
  pointer = { x: ev.clientX, y: ev.clientY };
  hover = pointer;
});

/** Client px → fractions of the drawn frame (outside [0, 1] over the bars). The rectangle is
 * the one drawn, zoomed included, so the gaze is the frame's point under the pointer. */
function frameFraction(p) {
  const box = canvas.getBoundingClientRect();
  const r = renderer.cssRect();
  return [(p.x - box.left - r.x) / r.width, (p.y - box.top - r.y) / r.height];
}

// ---- the inspector's zoom ---------------------------------------------------------------

/** Zoom (the wheel, + and -, 0: the whole frame; only while the inspector is open): the fitted
 * frame magnified about the pointer, its pixels drawn as blocks (renderer.view: the scale and
 * the offset, in fractions of the canvas). A zoomed frame always covers the canvas along a
 * side it is longer than; the gaze stays the frame point under the pointer (frameFraction). */
const ZOOM_MAX = 64;
const zoom = {
  /** Magnify by `factor` keeping the frame point under client px `p` (default: the middle
   * of the canvas) where it is. */
  by(factor, p = null) {
    const box = canvas.getBoundingClientRect();
    const v = renderer.view;
    const [px, py] = p ? [(p.x - box.left) / box.width, (p.y - box.top) / box.height] : [0.5, 0.5];
    const scale = Math.min(Math.max(v.scale * factor, 1), ZOOM_MAX, renderer.maxZoom());
    const k = scale / v.scale;
    this.set(scale, px - k * (px - v.x), py - k * (py - v.y));
  },
  /** Set the view, moved as little as keeps the frame covering the canvas. */
  set(scale, x, y) {
    if (scale <= 1) {
      renderer.view = { scale: 1, x: 0, y: 0 };
    } else {
      const f = renderer.fitRect();
      const { drawingBufferWidth: cw, drawingBufferHeight: ch } = renderer.gl;
      const keep = (o, start, size) => { // o: the offset; start, size: the fitted side's
        const [at, length] = [o + scale * start, scale * size]; // where the zoomed side lies
        const want = length >= 1 ? Math.min(Math.max(at, 1 - length), 0) : (1 - length) / 2;
        return want - scale * start;
      };
      renderer.view = { scale, x: keep(x, f.x / cw, f.width / cw), y: keep(y, f.y / ch, f.height / ch) };
    }
    inspector.zoom = renderer.view.scale;
    if (hover) pointer = hover; // another frame point is under the pointer now: the gaze
    showInspector();
  },
  reset() {
    this.set(1, 0, 0);
  },
};

// The wheel zooms about the pointer while the inspector is open (a pinch, ctrl+wheel, too).
window.addEventListener('wheel', (ev) => {
  if (!inspector.visible || (ev.target instanceof Element && ev.target.closest('#panel'))) return;
  ev.preventDefault();
  const lines = ev.deltaMode === 1 ? 33 : ev.deltaMode === 2 ? 400 : 1; // to px
  zoom.by(2 ** (-(ev.deltaY * lines) / 200), { x: ev.clientX, y: ev.clientY });
}, { passive: false });

function flushGaze() {
  if (!pointer) return;
  const [fx, fy] = frameFraction(pointer);
  if (!Number.isFinite(fx) || !Number.isFinite(fy)) return;
  const seq = gazeSeq + 1;
  // Not connected yet: keep the position, so the first gaze goes out as soon as it can.
  if (send(messages.gaze(fx, fy, seq))) {
    pointer = null;
    gazeSeq = seq;
    stats.gazeSent = seq;
    gazeSentAt[seq % SEQ_RING] = performance.now();
  }
}

function setEyes(open) {
  if (eyesClosed === !open) return;
  eyesClosed = !open;
  send(messages.eyes(open));
}

/** Keys go to a text field being typed in; everywhere else (a checkbox or a select that kept
 * the focus too) they are the viewer's. */
const TEXT_INPUTS = new Set(['text', 'number', 'search', 'email', 'url', 'password']);
const typing = (ev) =>
  ev.target instanceof HTMLElement &&
  (ev.target.isContentEditable || ev.target.tagName === 'TEXTAREA' || (ev.target.tagName === 'INPUT' && TEXT_INPUTS.has(ev.target.type)));
const KEYS = new Set(['h', 'p', 'f', 'r', 'i', 'c', 's', 'escape']);
/** The inspector's keys that repeat while held: exposure ([ ]) always, zoom (+ - 0) while the
 * inspector is open. */
const VIEW_KEYS = {
  '[': () => view.exposure(inspector.exposure - EXPOSURE_STEP),
  ']': () => view.exposure(inspector.exposure + EXPOSURE_STEP),
  '+': () => inspector.visible && zoom.by(2, hover),
  '=': () => inspector.visible && zoom.by(2, hover),
  '-': () => inspector.visible && zoom.by(1 / 2, hover),
  _: () => inspector.visible && zoom.by(1 / 2, hover),
  0: () => inspector.visible && zoom.reset(),
};

// Capture: before a focused select's type-ahead or a checkbox's Space can take the key.
window.addEventListener('keydown', (ev) => {
  if (ev.key === 'Escape' && panel.visible) {
    ev.preventDefault();
    document.activeElement?.blur?.();
    panel.toggle(false);
    return;
  }
  if (typing(ev) || ev.ctrlKey || ev.metaKey || ev.altKey) return;
  if (ev.code === 'Space') {
    ev.preventDefault();
    setEyes(false);
    return;
  }
  if (Object.hasOwn(VIEW_KEYS, ev.key)) {
    ev.preventDefault();
    VIEW_KEYS[ev.key]();
    return;
  }
  if (!KEYS.has(ev.key.toLowerCase())) return;
  ev.preventDefault();
  if (ev.repeat) return;
  switch (ev.key.toLowerCase()) {
    case 'h':
      hud.toggle();
      break;
    case 'p':
      panel.toggle();
      break;
    case 'f':
      if (document.fullscreenElement) document.exitFullscreen();
      else document.documentElement.requestFullscreen?.().catch(() => toast('fullscreen refused'));
      break;
    case 'r':
      send(messages.reset());
      break;
    case 'i':
      view.inspector();
      break;
    case 'c':
      view.falseColour();
      break;
    case 's':
      view.sceneView();
      break;
  }
}, true);
window.addEventListener('keyup', (ev) => {
  if (ev.code !== 'Space' || typing(ev)) return;
  ev.preventDefault(); // a focused checkbox would toggle
  setEyes(true);
}, true);

// Drag and drop anywhere: the file is uploaded under its own name.
const dropHint = document.getElementById('drop');
window.addEventListener('dragover', (ev) => {
  if (!ev.dataTransfer?.types.includes('Files')) return;
  ev.preventDefault();
  dropHint.hidden = false;
});
window.addEventListener('dragleave', (ev) => {
  if (!ev.relatedTarget) dropHint.hidden = true;
});
window.addEventListener('drop', (ev) => {
  ev.preventDefault();
  dropHint.hidden = true;
  const file = ev.dataTransfer?.files?.[0];
  if (file) panel.upload(file, file.name);
});
// A released key may never arrive (focus lost while held): open the eyes.
window.addEventListener('blur', () => setEyes(true));
document.addEventListener('visibilitychange', () => document.hidden && setEyes(true));

// ---- draw loop --------------------------------------------------------------------------

let hudAt = 0;

function hudInfo(now) {
  return {
    header: lastHeader,
    connection: conn.describe(now),
    session: conn.session,
    frameRate: stats.frames.rate(now),
    drawRate: stats.draws.rate(now),
    latencyP50: stats.latency.percentile(50),
    latencyP95: stats.latency.percentile(95),
    scene: state.scene,
    model: state.model,
    split: state.split,
    preset: state.preset,
    gazeSource: state.gaze_source,
    tracker: trackerStatus(state.gaze_source ?? ''),
  };
}

/** The HUD's tracker line: the tracker this session follows, or what it waits for. */
function trackerStatus(source) {
  const connected = [...trackers.values()].filter((t) => t.connected);
  if (source.startsWith('remote:')) {
    const name = source.slice('remote:'.length);
    const t = trackers.get(name);
    return t?.connected ? `${name} · ${t.samples} samples` : `${name} · not connected`;
  }
  if (source === 'remote') {
    return connected.length > 1 ? `${connected.length} connected: choose one` : 'waiting for one';
  }
  return connected.length ? `${connected.length} connected, not followed` : 'not connected';
}

/** Where a warp frame places its afterimages, as frame fractions: the newest pointer while the
 * pointer is the gaze, the newest forwarded gaze while a daemon's tracker is; else null, the
 * frame's own gaze (a track's, or a tracker's until its first note). With the eyes closed a
 * tracker's note keeps the place it had (the server holds it through a blink, as the model does). */
function warpGaze() {
  if (lastHeader?.tracker_gaze) return trackerGaze && { x: trackerGaze.x, y: trackerGaze.y };
  if (!hover || !lastHeader) return null;
  const [x, y] = frameFraction(hover);
  return Number.isFinite(x) && Number.isFinite(y) ? { x, y } : null;
}

function tick(now) {
  requestAnimationFrame(tick);
  if (pending && !api.hold) {
    const { header: h, pixels } = pending;
    pending = null;
    renderer.upload(h.width, h.height, h.encoding, pixels);
    api.shown = h; // the header of the frame on the screen
  }
  if (pendingPlanes) {
    renderer.uploadYuv(pendingPlanes);
    pendingPlanes = null;
  }
  if (renderer.fitToCSS() && renderer.view.scale !== 1) {
    const v = renderer.view; // a resized canvas: the zoomed frame still covers it
    zoom.set(v.scale, v.x, v.y);
  }
  flushGaze();
  // Every display frame: the dither noise must change even without new frames, and a warp
  // frame's afterimages follow the newest pointer (when the pointer is the gaze).
  renderer.draw(undefined, warpGaze());
  stats.draws.tick(now);
  const rect = renderer.cssRect();
  hud.placeMarker(lastHeader, rect);
  splitOverlay.place(lastHeader, rect, state.model, state.split);
  inspector.place(lastHeader, rect, canvas.getBoundingClientRect());
  if (now - hudAt >= HUD_INTERVAL_MS) {
    hudAt = now;
    hud.update(hudInfo(now));
    showStatus(now);
    const [fx, fy] = hover ? frameFraction(hover) : [NaN, NaN];
    inspector.update(fx, fy, lastHeader, lastPayload, state);
  }
}

// For tests and debugging; keep it small.
const api = {
  state, lastHeader, stats, lastPayload, renderer, connection: conn, trackers, inspector,
  sceneMap: null, sceneMaps: 0, panel, view, zoom, hud, video, encodingRefused: null,
  shown: null,
  get trackerGaze() { return trackerGaze; }, // the newest forwarded tracker gaze (`gaze` notes)
  hold: false, // tests: keep showing the current frame (frames still arrive), as a stalled server
}; // prettier-ignore
window.gazehdr = api;

conn.open();
requestAnimationFrame(tick);
