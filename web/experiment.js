// The experiment page (docs/experiments.md): consent and observer id, instructions, then per
// trial: fetch the pre-rendered frames, play them on their simulation times with the viewer's
// renderer (temporal dithering), ask, time the key press from the prompt, post the answer.
// window.gazehdrExperiment exposes the state for tests and for the experimenter's console.

import { decodeFrame, decodeHeader, ENCODING } from './protocol.js';
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

/** The unique frames of a trial, by frame index (a missing index repeats the one before). */
function splitFrames(buffer) {
  const byIndex = new Map();
  for (let at = 0; at < buffer.byteLength; ) {
    const h = decodeHeader(buffer.slice(at, at + 64));
    const size = h.header_bytes + h.width * h.height * (h.encoding === ENCODING.F16 ? 6 : 4);
    byIndex.set(h.frame, decodeFrame(buffer.slice(at, at + size)));
    at += size;
  }
  return byIndex;
}

/** Play the frames at their simulation times; resolves when the last one has had its time. */
function play(trial, frames) {
  const times = trial.frames.map((f) => f[0] - trial.frames[0][0]);
  const total = trial.end - trial.frames[0][0];
  return new Promise((resolve) => {
    let start = null;
    let current = -1;
    const tick = (now) => {
      if (start === null) start = now;
      const elapsed = (now - start) / 1000;
      if (elapsed >= total) {
        renderer.frame = null; // the prompt is black
        renderer.draw();
        resolve();
        return;
      }
      let i = current < 0 ? 0 : current;
      while (i + 1 < times.length && times[i + 1] <= elapsed) i++;
      if (i !== current) {
        let k = i;
        while (!frames.has(k)) k--;
        const { header, pixels } = frames.get(k);
        renderer.upload(header.width, header.height, header.encoding, pixels);
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

async function trialLoop() {
  for (;;) {
    show('loading', '');
    const trial = await (await api(`/runs/${run}/trial`)).json();
    const frames = splitFrames(await (await api(`/runs/${run}/trial/frames`)).arrayBuffer());
    ex.trial = trial.trial;
    show('playing');
    await play(trial, frames);
    show('prompt', design.texts.question);
    const prompt = performance.now();
    const { key, at } = await nextKey(design.keys);
    const rt = (at - prompt) / 1000;
    const out = await (await post(`/runs/${run}/response`, {
      trial: trial.trial, key, response_time: rt,
    })).json();
    ex.answers.push({ trial: trial.trial, key, response_time: rt, ...out });
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
        observer: $('observer').value, consent: $('agree').checked,
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
