// The experiment page (docs/experiments.md): consent and observer id, instructions, then per
// trial: fetch the pre-rendered frames, play them on their simulation times with the viewer's
// renderer (temporal dithering), ask, time the key press from the prompt, post the answer.
// window.gazehdrExperiment exposes the state for tests and for the experimenter's console.

import { BYTES_PER_PIXEL, decodeFrame, decodeHeader } from './protocol.js';
import { Renderer } from './renderer.js';

const $ = (id) => document.getElementById(id);
const ex = (window.gazehdrExperiment = { state: 'consent', trial: 0, answers: [], shown: 0 });
const renderer = new Renderer($('view'));
let design = null;
let run = null;

async function api(path, options = {}) {
  const res = await fetch(`/api/experiment${path}`, { credentials: 'same-origin', ...options });
  if (!res.ok) {
    const body = await res.json().catch(() => ({}));
    throw new Error(typeof body.detail === 'string' ? body.detail : `${res.status} ${path}`);
  }
  return res;
}

function post(path, body) {
  return api(path, {
    method: 'POST',
    headers: { 'Content-Type': 'application/json' },
    body: JSON.stringify(body),
  });
}

function show(state, text = null) {
  ex.state = state;
  $('consent').hidden = state !== 'consent';
  $('message').hidden = text === null;
  if (text !== null) $('message-text').textContent = text;
  document.body.classList.toggle('form', state === 'consent');
}

function placeFixation() {
  const r = renderer.cssRect();
  const [fx, fy] = design.fixation;
  const f = $('fixation');
  f.style.left = `${r.x + fx * r.width}px`;
  f.style.top = `${r.y + fy * r.height}px`;
  f.hidden = false;
}

const keyName = (e) => (e.key === ' ' ? 'Space' : e.key);

function nextKey(allowed) {
  return new Promise((resolve) => {
    const on = (e) => {
      const name = keyName(e);
      if (allowed && !allowed.includes(name)) return;
      window.removeEventListener('keydown', on);
      resolve({ key: name, at: performance.now() });
    };
    window.addEventListener('keydown', on);
  });
}

/**
 * A trial's frames as they arrive (frame messages one after another; a frame equal to the one
 * before is not sent): `frames` by index, `last` the newest index in, `done` when all are.
 * Frames come in index order, so index i is in when `done || last >= i`.
 */
function streamFrames(response) {
  const got = { frames: new Map(), last: -1, done: false, failed: null };
  const reader = response.body.getReader();
  // Bytes in, not yet framed: buf[start, end), grown by doubling, so that a frame arriving in
  // many chunks is copied once into it and once out (its own buffer), not once per chunk.
  let buf = new Uint8Array(1 << 16);
  let start = 0;
  let end = 0;
  const append = (chunk) => {
    if (end + chunk.length > buf.length) {
      const held = end - start;
      if (held + chunk.length > buf.length) {
        const grown = new Uint8Array(2 * (held + chunk.length));
        grown.set(buf.subarray(start, end));
        buf = grown;
      } else {
        buf.copyWithin(0, start, end); // room enough once what is held moves to the front
      }
      start = 0;
      end = held;
    }
    buf.set(chunk, end);
    end += chunk.length;
  };
  (async () => {
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      append(value);
      while (end - start >= 8) {
        const headerBytes = new DataView(buf.buffer, start + 6, 2).getUint16(0, true);
        if (end - start < headerBytes) break;
        const h = decodeHeader(buf.buffer.slice(start, start + headerBytes));
        const bpp = BYTES_PER_PIXEL[h.encoding];
        if (bpp === undefined) throw new Error(`a trial frame in encoding ${h.encoding}, not f16 or rgb10a2`);
        const size = headerBytes + h.width * h.height * bpp;
        if (end - start < size) break;
        const frame = decodeFrame(buf.buffer.slice(start, start + size));
        got.frames.set(frame.header.frame, frame);
        got.last = frame.header.frame;
        start += size;
      }
    }
  })()
    .catch((e) => {
      got.failed = e;
    })
    .finally(() => {
      got.done = true;
    });
  return got;
}

const has = (got, i) => got.done || got.last >= i;
const LEAD_S = 1.0; // playback starts with this much of the trial in (or all of it)

/**
 * Play the frames at their simulation times; resolves with the number of frames not shown at
 * their time: not yet received, or passed over when the display loop came late (the one before
 * was held longer: 0 is a trial as rendered).
 */
async function play(trial, got) {
  const times = trial.frames.map((f) => f[0] - trial.frames[0][0]);
  const total = trial.end - trial.frames[0][0];
  const lead = times.findIndex((t) => t >= LEAD_S);
  while (!has(got, lead < 0 ? times.length - 1 : lead)) {
    if (got.failed) throw got.failed;
    await new Promise((r) => setTimeout(r, 10));
  }
  return new Promise((resolve) => {
    let start = null;
    let current = -1;
    let late = 0;
    let lateUpTo = -1; // frames up to this index are counted already
    const tick = (now) => {
      if (start === null) start = now;
      const elapsed = (now - start) / 1000;
      if (elapsed >= total) {
        renderer.frame = null; // the prompt is black
        renderer.draw();
        late += times.length - 1 - Math.max(current, lateUpTo); // never shown at all
        resolve(late);
        return;
      }
      let i = current < 0 ? 0 : current;
      while (i + 1 < times.length && times[i + 1] <= elapsed) i++;
      const wanted = i;
      while (i > current && !has(got, i)) i--;
      // Every frame due by now but the one shown, not yet received or passed over because
      // this loop came late, is late: counted once each.
      for (let j = Math.max(current, lateUpTo) + 1; j <= wanted; j++) if (j !== i) late++;
      lateUpTo = Math.max(lateUpTo, wanted);
      if (i !== current) {
        let k = i;
        while (!got.frames.has(k)) k--;
        const { header, pixels } = got.frames.get(k);
        renderer.upload(header.width, header.height, header.encoding, pixels);
        for (const old of got.frames.keys()) if (old < k) got.frames.delete(old);
        current = i;
        ex.shown++;
      }
      renderer.fitToCSS();
      renderer.draw();
      placeFixation();
      requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
  });
}

/**
 * Where each option goes when every label is a column letter and a row number (Fig. 15: A1 …
 * H4): {columns, rows, at: label -> [column, row]} (1-based, columns and rows sorted), else
 * null, and the options flow in the design's order.
 */
function paletteCells(labels) {
  const parts = labels.map((l) => /^([A-Za-z]+)(\d+)$/.exec(l));
  if (!parts.every(Boolean)) return null;
  const columns = [...new Set(parts.map((p) => p[1]))].sort();
  const rows = [...new Set(parts.map((p) => Number(p[2])))].sort((a, b) => a - b);
  const at = new Map(parts.map((p) => [
    p[0], [columns.indexOf(p[1]) + 1, rows.indexOf(Number(p[2])) + 1],
  ]));
  return { columns: columns.length, rows: rows.length, at };
}

/** Sec. 4.3: the observer clicks the options like the afterimage seen, then presses Enter. */
async function pickFromPalette() {
  const grid = $('palette');
  if (!grid.childElementCount) {
    const cells = paletteCells(design.palette);
    // A column per letter, a row per number; each (square) image as large as the window's
    // height and width allow for that many rows and columns, its caption and border included.
    const side = cells && `min(calc((100vh - 4em) / ${cells.rows} - 2.6em), `
      + `calc((100vw - 2em) / ${cells.columns} - 0.9em))`;
    if (cells) {
      Object.assign(grid.style, {
        display: 'grid', placeContent: 'center',
        gridTemplateColumns: `repeat(${cells.columns}, auto)`,
      });
    }
    for (const label of design.palette) {
      const option = document.createElement('figure');
      option.dataset.label = label;
      const img = document.createElement('img');
      img.src = `/api/experiment/palette/${label}.png`;
      img.alt = label;
      const caption = document.createElement('figcaption');
      caption.textContent = label;
      option.append(img, caption);
      if (cells) {
        const [column, row] = cells.at.get(label);
        Object.assign(option.style, {
          gridColumn: String(column), gridRow: String(row), width: 'auto',
        });
        Object.assign(img.style, { width: side, height: side });
      }
      option.addEventListener('click', () => option.classList.toggle('picked'));
      grid.append(option);
    }
  }
  for (const option of grid.children) option.classList.remove('picked');
  $('fixation').hidden = true;
  grid.hidden = false;
  document.body.classList.add('picking');
  for (;;) {
    const { at } = await nextKey(['Enter']);
    const picked = [...grid.querySelectorAll('.picked')].map((o) => o.dataset.label);
    if (picked.length) {
      document.body.classList.remove('picking');
      return { palette: picked, at };
    }
  }
}

async function trialLoop() {
  for (;;) {
    show('loading', '');
    const slow = setTimeout(() => show('loading', 'Preparing the images…'), 500);
    let trial;
    try {
      trial = await (await api(`/runs/${run}/trial`)).json();
    } finally {
      clearTimeout(slow);
    }
    const got = streamFrames(await api(`/runs/${run}/trial/frames`));
    if (trial.intro) {
      show('intro', `${trial.intro} (Press Space to go on.)`);
      await nextKey(['Space']);
    }
    ex.trial = trial.trial;
    show('playing');
    const late = await play(trial, got);
    show('prompt', design.texts.question);
    const prompt = performance.now();
    const answer = trial.palette ? await pickFromPalette() : await nextKey(design.keys);
    $('palette').hidden = true;
    const rt = (answer.at - prompt) / 1000;
    const { key = null, palette = null } = answer;
    const out = await (await post(`/runs/${run}/response`, {
      trial: trial.trial, key, palette, response_time: rt, frames_late: late,
    })).json();
    ex.answers.push({ trial: trial.trial, key, palette, response_time: rt, frames_late: late, ...out });
    if (out.feedback) {
      show('feedback', out.feedback);
      await new Promise((r) => setTimeout(r, 700));
    }
    if (out.finished) {
      $('fixation').hidden = true;
      show('done', out.excluded ? design.texts.excluded : design.texts.thanks);
      ex.result = out;
      return;
    }
  }
}

async function main() {
  design = await (await api('')).json();
  ex.design = design;
  $('title').textContent = design.title;
  $('consent-text').textContent = design.texts.consent;
  $('start').addEventListener('submit', async (e) => {
    e.preventDefault();
    try {
      const started = await (await post('/runs', {
        observer: $('observer').value,
        consent: $('agree').checked,
        run: $('run').value ? Number($('run').value) : null,
      })).json();
      run = ex.run = started.run;
    } catch (err) {
      $('error').textContent = err.message;
      return;
    }
    show('instructions', `${design.texts.instructions} (Press Space to begin.)`);
    await nextKey(['Space']);
    trialLoop().catch((err) => show('error', `The experiment stopped: ${err.message}`));
  });
  show('consent');
}

main().catch((err) => {
  ex.error = err.message;
  show('error', `Cannot load the experiment: ${err.message}`);
});
