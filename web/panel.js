// Side panel: scene (and its scale in cd/m² per unit) / view / models (and split view) / gaze
// source, the model's parameters grouped by paper section with symbol, unit and meaning,
// presets and upload. It only builds messages; main.js sends them. Escape or × closes it.

import { messages } from './protocol.js';

/** Values edited as text would be a trap: matrices and geometry are shown read-only. */
const READ_ONLY = new Set(['H', 'geometry']);

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === 'class') e.className = v;
    else if (k in e) e[k] = v;
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c);
  return e;
}

const isNumberVector = (v) => Array.isArray(v) && v.length <= 4 && v.every((x) => typeof x === 'number');

export class Panel {
  /**
   * @param {HTMLElement} root
   * @param {(msg: object) => void} send
   * @param {(text: string) => void} toast
   */
  constructor(root, send, toast, view) {
    this.root = root;
    this.send = send;
    this.toast = toast;
    this.view = view; // main.js's: what the page shows (the views, the inspector's settings)
    this.visible = false;
    this.layoutKey = null; // rebuild parameter inputs only when the set of names changes
    this.inputs = new Map(); // name -> {update(value)}
    this.presets = {};
    root.hidden = true;
    this.build();
  }

  toggle(visible = !this.visible) {
    this.visible = visible;
    this.root.hidden = !visible;
  }

  build() {
    this.sceneSelect = el('select', { id: 'scene-select' });
    this.sceneInfo = el('div', { class: 'scene-info', id: 'scene-info' });
    this.scaleInput = el('input', { type: 'number', id: 'scale-input', step: 'any', min: 0, title: 'cd/m² per unit of the file' });
    this.kindSelect = el('select', { id: 'kind-select', title: 'the estimate\'s scene kind (exposure table)' });
    this.layerSelect = el('select', { id: 'layer-select' });
    const scaleDefault = el('button', { type: 'button', textContent: 'default', title: 'the file\'s scale, else the estimate' });
    this.scaleInput.addEventListener('change', () => {
      const v = Number(this.scaleInput.value);
      if (!(v > 0) || !Number.isFinite(v)) return this.scaleInput.classList.add('invalid');
      this.scaleInput.classList.remove('invalid');
      this.send(messages.sceneSettings({ scale: v }));
    });
    this.kindSelect.addEventListener('change', () => this.send(messages.sceneSettings({ scale: null, kind: this.kindSelect.value })));
    this.layerSelect.addEventListener('change', () => this.send(messages.sceneSettings({ layer: this.layerSelect.value })));
    scaleDefault.addEventListener('click', () => this.send(messages.sceneSettings({ scale: null, kind: null })));
    this.falseColourBox = el('input', { type: 'checkbox', id: 'falsecolour-toggle' });
    this.inspectorBox = el('input', { type: 'checkbox', id: 'inspector-toggle' });
    this.falseColourBox.addEventListener('change', () => this.view.falseColour(this.falseColourBox.checked));
    this.inspectorBox.addEventListener('change', () => this.view.inspector(this.inspectorBox.checked));
    this.warpBox = el('input', { type: 'checkbox', id: 'warp-toggle' });
    this.warpBox.addEventListener('change', () => this.view.warp(this.warpBox.checked));
    const plain = el('button', { type: 'button', id: 'plain-compare', textContent: 'Compare: plain tone curve' });
    plain.title = 'split view: the right pane without afterimages or acuity loss';
    plain.addEventListener('click', () => {
      const left = { afterimage: this.afterimageSelect.value, acuity: this.acuitySelect.value };
      this.send(messages.model(left, { afterimage: 'none', acuity: 'none' }));
    });
    this.afterimageSelect = el('select', { id: 'afterimage-select' });
    this.acuitySelect = el('select', { id: 'acuity-select' });
    this.splitBox = el('input', { type: 'checkbox', id: 'split-toggle' });
    this.splitAfterimageSelect = el('select', { id: 'split-afterimage-select' });
    this.splitAcuitySelect = el('select', { id: 'split-acuity-select' });
    this.sourceSelect = el('select', { id: 'source-select' });
    this.sceneSelect.addEventListener('change', () => this.send(messages.scene(this.sceneSelect.value)));
    for (const control of [
      this.afterimageSelect,
      this.acuitySelect,
      this.splitBox,
      this.splitAfterimageSelect,
      this.splitAcuitySelect,
    ]) {
      control.addEventListener('change', () => this.sendModels());
    }
    this.sourceSelect.addEventListener('change', () =>
      this.send(messages.gazeSource(this.sourceSelect.value)),
    );
    // The presets (paper: the paper's values; visible: ours for a plain monitor); choosing one
    // sets every parameter to its values. The live one is named beside: "paper + j1" after edits.
    this.presetSelect = el('select', { id: 'preset-select', title: 'set every parameter to a preset' });
    this.presetSelect.addEventListener('change', () => {
      const values = this.presets[this.presetSelect.value];
      if (values) this.send(messages.params({ ...values }));
    });
    this.presetLive = el('span', { id: 'preset-live', class: 'hint' });
    const reset = el('button', { type: 'button', textContent: 'Reset eye' });
    reset.addEventListener('click', () => this.send(messages.reset()));

    this.fileInput = el('input', { type: 'file', accept: '.exr,.hdr,.pic,.pfm' });
    this.uploadName = el('input', { type: 'text', placeholder: 'scene name', size: 12 });
    this.fileInput.addEventListener('change', () => {
      const f = this.fileInput.files[0];
      if (f && !this.uploadName.value) this.uploadName.value = sceneName(f.name);
    });
    const upload = el('button', { type: 'button', id: 'upload-button', textContent: 'Upload' });
    upload.addEventListener('click', () => {
      const file = this.fileInput.files[0];
      if (!file) return this.toast('choose an image file first (.exr, .hdr, .pfm)');
      this.upload(file, this.uploadName.value || file.name);
    });
    const close = el('button', { type: 'button', class: 'close', id: 'panel-close', textContent: '×', title: 'close (Esc)' });
    close.addEventListener('click', () => this.toggle(false));

    this.inspectorGroup = this.buildInspector();
    this.params = el('div', { class: 'params' });
    this.root.append(
      el('h2', {}, 'gazehdr', close),
      el('label', {}, 'scene ', this.sceneSelect),
      this.sceneInfo,
      el('div', { class: 'row' }, el('label', {}, 'cd/m² per unit ', this.scaleInput), scaleDefault),
      el('label', {}, 'estimate for ', this.kindSelect),
      el('label', { id: 'layer-row' }, 'layer ', this.layerSelect),
      el('label', {}, this.falseColourBox, ' false colour (C)'),
      el('label', {}, this.inspectorBox, ' inspector: readout, histogram (I)'),
      this.inspectorGroup,
      el('label', { title: 'afterimages follow the pointer at display rate, between frames' }, this.warpBox, ' late gaze warp'),
      el('label', {}, 'afterimage ', this.afterimageSelect),
      el('label', {}, 'acuity ', this.acuitySelect),
      el('label', {}, this.splitBox, ' split view: right pane'),
      el('div', { class: 'row split-models' }, this.splitAfterimageSelect, this.splitAcuitySelect),
      el('label', {}, 'gaze ', this.sourceSelect),
      el('div', { class: 'row' }, plain),
      el('div', { class: 'row' }, el('label', {}, 'preset ', this.presetSelect), this.presetLive, reset),
      el('div', { class: 'row' }, this.fileInput),
      el('div', { class: 'row' }, this.uploadName, upload),
      this.params,
      el('p', { class: 'hint' }, 'H HUD · P panel · Esc close · I inspector · C false colour · F fullscreen · R reset · hold Space: eyes closed · drop a file anywhere to upload'),
    );
  }

  /** The inspector's controls: the scene view and its exposure, the false colour's range,
   * the zoom. They change what this page draws, never the simulation or what is sent. */
  buildInspector() {
    const button = (text, title, click) => {
      const b = el('button', { type: 'button', textContent: text, title });
      b.addEventListener('click', click);
      return b;
    };
    const number = (id, title, step) => el('input', { type: 'number', id, title, step, class: 'short' });
    this.sceneViewBox = el('input', { type: 'checkbox', id: 'sceneview-toggle' });
    this.sceneViewBox.addEventListener('change', () => this.view.sceneView(this.sceneViewBox.checked));
    this.exposureInput = number('exposure-input', 'stops: the file\'s values × 2^exposure', 0.5);
    this.exposureInput.addEventListener('change', () => {
      const v = Number(this.exposureInput.value);
      const ok = this.exposureInput.value.trim() !== '' && Number.isFinite(v);
      this.exposureInput.classList.toggle('invalid', !ok);
      if (ok) this.view.exposure(v);
    });
    this.rangeInputs = [
      number('falsecolour-min', 'log10 cd/m² shown darkest', 0.5),
      number('falsecolour-max', 'log10 cd/m² shown brightest', 0.5),
    ];
    const commitRange = () => {
      const [lo, hi] = this.rangeInputs.map((f) => (f.value.trim() === '' ? NaN : Number(f.value)));
      const ok = this.view.falseRange([lo, hi]);
      for (const f of this.rangeInputs) f.classList.toggle('invalid', !ok);
    };
    for (const f of this.rangeInputs) f.addEventListener('change', commitRange);
    this.zoomLabel = el('span', { id: 'zoom-label', class: 'hint' });
    return el(
      'fieldset', { class: 'inspector-group', id: 'inspector-group' },
      el('legend', {}, 'inspector view (this page only)'),
      el('label', { title: 'the file\'s values in its own units × 2^exposure, as tev shows them' },
        this.sceneViewBox, ' scene view: the file × 2^exposure (S)'),
      el('div', { class: 'row' },
        el('label', {}, 'exposure ', this.exposureInput, ' stops ([ ])'),
        button('0', 'exposure 0: the file\'s value 1 is white', () => this.view.exposure(0)),
        button('fit', 'the brightest 1% of the scene at white', () => this.view.exposure('fit'))),
      el('div', { class: 'row' },
        el('label', {}, 'false colour ', this.rangeInputs[0], ' to ', this.rangeInputs[1], ' log10 cd/m²'),
        button('default', 'log10 cd/m² −3 to 7', () => this.view.falseRange(null)),
        button('fit', 'the scene\'s darkest to its brightest lit pixel', () => this.view.falseRange('fit'))),
      el('div', { class: 'row' },
        this.zoomLabel,
        button('whole frame', 'zoom 1× (0)', () => this.view.zoomReset())),
    ); // prettier-ignore
  }

  /** The inspector's settings as the page has them (keys change them too); a field being
   * edited is left alone. */
  showInspector({ sceneView, exposure, range, zoom }) {
    this.sceneViewBox.checked = sceneView;
    const show = (field, v) => {
      if (document.activeElement === field) return;
      field.value = String(v);
      field.classList.remove('invalid');
    };
    show(this.exposureInput, exposure);
    this.rangeInputs.forEach((f, i) => show(f, range[i]));
    this.zoomLabel.textContent = `zoom ${Number(zoom.toPrecision(3))}× (wheel, + −; 0: whole frame)`;
  }

  /** The whole model choice as one message: the server applies it at once. */
  sendModels() {
    const pick = (a, b) => ({ afterimage: a.value, acuity: b.value });
    const split = this.splitBox.checked ? pick(this.splitAfterimageSelect, this.splitAcuitySelect) : null;
    this.send(messages.model(pick(this.afterimageSelect, this.acuitySelect), split));
  }

  /** The view toggles as the page has them (keys change them too). */
  showWarp(on) {
    this.warpBox.checked = on;
  }

  showView(falseColour, inspector) {
    this.falseColourBox.checked = falseColour;
    this.inspectorBox.checked = inspector;
  }

  /** Refresh from a hello/state message. */
  update(state) {
    fillSelect(this.sceneSelect, state.scenes, state.scene);
    const info = state.scene_info;
    if (info) {
      const size = info.width ? ` ${info.width}×${info.height}` : '';
      this.sceneInfo.textContent = `${info.format}${size} · ${Number(info.scale.toPrecision(4))} cd/m² per unit: ${info.scale_note}`;
      this.sceneInfo.title = [...(info.notes ?? [])].join('\n');
      const fixed = info.scale_source === 'built-in';
      for (const c of [this.scaleInput, this.kindSelect]) c.disabled = fixed;
      if (document.activeElement !== this.scaleInput) this.scaleInput.value = String(Number(info.scale.toPrecision(6)));
      fillSelect(this.kindSelect, Object.keys(state.scene_kinds ?? {}), info.kind ?? '');
      fillSelect(this.layerSelect, info.layers, info.layer);
      this.layerSelect.parentElement.hidden = (info.layers ?? []).length < 2;
    }
    const models = state.models ?? {};
    const model = state.model ?? {};
    fillSelect(this.afterimageSelect, models.afterimage, model.afterimage);
    fillSelect(this.acuitySelect, models.acuity, model.acuity);
    // Split off: the right pane's choosers keep what the user picked, ready for the toggle.
    const right = (select, part) => {
      fillSelect(select, models[part], state.split?.[part] ?? (select.value || model[part]));
    };
    right(this.splitAfterimageSelect, 'afterimage');
    right(this.splitAcuitySelect, 'acuity');
    if (state.split !== undefined) this.splitBox.checked = state.split !== null;
    fillSelect(this.sourceSelect, state.gaze_sources, state.gaze_source);
    this.presets = state.presets ?? {};
    const live = state.preset ?? '';
    fillSelect(this.presetSelect, Object.keys(this.presets), live.split(' ')[0]);
    this.presetLive.textContent = live.includes(' ') ? live : '';
    const params = state.params ?? {};
    const key = JSON.stringify([Object.keys(params).sort(), state.sections]);
    if (key !== this.layoutKey) {
      this.layoutKey = key;
      this.buildParams(params, state.sections ?? {}, state.param_info ?? {});
    }
    for (const [name, value] of Object.entries(params)) this.inputs.get(name)?.update(value);
  }

  buildParams(params, sections, info) {
    this.params.replaceChildren();
    this.inputs.clear();
    const placed = new Set();
    const groups = Object.entries(sections).map(([title, names]) => [title, names]);
    const rest = Object.keys(params).filter((n) => !Object.values(sections).some((ns) => ns.includes(n)));
    if (rest.length) groups.push(['other', rest]);
    for (const [title, names] of groups) {
      const fieldset = el('fieldset', {}, el('legend', {}, title));
      for (const name of names) {
        if (!(name in params) || placed.has(name)) continue;
        placed.add(name);
        fieldset.append(this.paramRow(name, params[name], info[name] ?? {}));
      }
      this.params.append(fieldset);
    }
  }

  paramRow(name, value, info) {
    const label = el('span', { class: 'name', title: info.ours ? 'ours: not given by the paper' : 'the paper\'s' });
    label.append(el('span', { class: 'symbol' }, info.symbol ?? ''), name);
    if (info.ours) label.append(el('sup', { class: 'ours' }, 'ours'));
    label.append(el('span', { class: 'unit' }, info.unit && info.unit !== '—' ? `[${info.unit}]` : ''));
    const row = el('div', { class: 'param' }, label, el('span', { class: 'meaning' }, info.meaning ?? ''));
    if (READ_ONLY.has(name) || !(typeof value === 'number' || typeof value === 'boolean' || isNumberVector(value))) {
      const code = el('code', { class: 'readonly' });
      row.append(code);
      this.inputs.set(name, { update: (v) => (code.textContent = JSON.stringify(v)) });
      return row;
    }
    if (typeof value === 'boolean') {
      const box = el('input', { type: 'checkbox' });
      box.addEventListener('change', () => this.send(messages.params({ [name]: box.checked })));
      row.append(box);
      this.inputs.set(name, { update: (v) => (box.checked = v) });
      return row;
    }
    const n = Array.isArray(value) ? value.length : 1;
    const fields = Array.from({ length: n }, () => el('input', { type: 'number', step: 'any' }));
    const commit = () => {
      const nums = fields.map((f) => Number(f.value));
      const bad = fields.filter((f, i) => f.value.trim() === '' || !Number.isFinite(nums[i]));
      for (const f of fields) f.classList.toggle('invalid', bad.includes(f));
      if (bad.length) return;
      this.send(messages.params({ [name]: Array.isArray(value) ? nums : nums[0] }));
    };
    for (const f of fields) {
      f.addEventListener('change', commit);
      row.append(f);
    }
    this.inputs.set(name, {
      update: (v) => {
        const vs = Array.isArray(v) ? v : [v];
        fields.forEach((f, i) => {
          if (document.activeElement !== f) f.value = String(vs[i]); // never fight the user
          f.classList.remove('invalid');
        });
      },
    });
    return row;
  }

  /** Upload `file` as scene `name`; an existing one is replaced only if the user agrees. */
  async upload(file, name) {
    name = sceneName(name);
    if (!name) return this.toast('give the scene a name');
    const put = (overwrite) =>
      fetch(`/api/scenes/${encodeURIComponent(name)}${overwrite ? '?overwrite=true' : ''}`, {
        method: 'PUT',
        headers: { 'Content-Type': 'application/octet-stream' },
        body: file,
      });
    try {
      let res = await put(false);
      if (res.status === 409) {
        if (!window.confirm(`A scene named “${name}” exists. Replace it?`)) return this.toast(`not uploaded: “${name}” kept`);
        res = await put(true);
      }
      if (!res.ok) {
        let detail = await res.text();
        try {
          detail = JSON.parse(detail).detail ?? detail;
        } catch {
          /* plain text */
        }
        return this.toast(`upload refused (${res.status}): ${typeof detail === 'string' ? detail : JSON.stringify(detail)}`);
      }
      this.send(messages.scene(name));
    } catch (err) {
      this.toast(`upload failed: ${err.message}`);
    }
  }
}

/** A file name to a scene name: base name, safe characters only. */
function sceneName(filename) {
  return filename
    .replace(/\.(exr|hdr|pic|pfm)$/i, '')
    .replace(/[^A-Za-z0-9_.-]+/g, '-')
    .replace(/^[-.]+|[-.]+$/g, '')
    .slice(0, 64);
}

function fillSelect(select, options, current) {
  if (!Array.isArray(options)) return;
  const key = options.join('\n');
  if (select.dataset.key !== key) {
    select.replaceChildren(...options.map((o) => el('option', { value: o, textContent: o })));
    select.dataset.key = key;
  }
  if (current != null && document.activeElement !== select) select.value = current;
}
