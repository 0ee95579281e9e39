// The hybrid-octree viewer page: sends the whole view state over a WebSocket whenever it changes
// and paints the frames the server renders. Coordinates are patient millimetres (LPS).
'use strict';

const $ = (id) => document.getElementById(id);

// ---- small vector maths ---------------------------------------------------------------------
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => Math.hypot(a[0], a[1], a[2]);
const unit = (a) => mul(a, 1 / norm(a));
// Rodrigues: v turned by angle (radians) about unit axis k.
function rotate(v, k, angle) {
  const c = Math.cos(angle), s = Math.sin(angle);
  return add(add(mul(v, c), mul(cross(k, v), s)), mul(k, dot(k, v) * (1 - c)));
}

// ---- state ----------------------------------------------------------------------------------
const state = {
  info: null,               // the open volume (from the server)
  camera: null,             // {eye, center, up, fov}
  preset: '',
  basePoints: [],           // the preset's (or the edited) control points
  window: 1, level: 0,      // of basePoints, as window/level: values mapped linearly
  baseWindow: 1, baseLevel: 0,
  edited: false,
  opacity: 1,
  seq: 0,
  sent: new Map(),          // seq -> time sent
  metrics: [],              // one entry per painted frame
  lastFinal: null,          // {header, blob}
  surfaceStates: {},         // isovalue -> 'building' | 'ready' | 'failed', of the volume shown
  simplifying: null,         // the isovalue whose ready surface the builder still simplifies for moving frames
  opening: null,             // the scene key of a volume asked for and not shown yet
  openingLabel: '',          // ... as the volume menu calls it
  loads: [],                 // the loading messages heard: {scene, task, progress}
  opened: [],                // the volumes shown, in order: {scene, at}
  errors: [],
};

const canvas = $('view');
const ctx = canvas.getContext('2d');
let socket = null;

function imageSize() { return Number($('size').value); }

// The control points sent: the base points through window/level.
function currentPoints() {
  const scale = state.window / state.baseWindow;
  return state.basePoints.map(([v, r, g, b, a]) => [state.level + (v - state.baseLevel) * scale, r, g, b, a]);
}

// The transfer function's fields of a frame message: a preset, or points when edited.
function tfFields() {
  const plain = !state.edited && state.window === state.baseWindow && state.level === state.baseLevel && state.preset;
  return { ...(plain ? { preset: state.preset } : { tf_points: currentPoints() }), opacity: state.opacity };
}

// The surface's fields: no isovalue, no surface.
// A colour input's #rrggbb as r, g, b in [0, 1].
const rgbOf = (hex) => [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16) / 255);

function surfaceFields() {
  if (!$('surface-on').checked) return { iso: null };
  return { iso: Number($('iso').value), surface_color: [...rgbOf($('surface-color').value), Number($('surface-alpha').value)] };
}

// The user's geometry: a mesh file of the data directory and primitives (Levoy's plane, sphere,
// polygon), in the colour picked unless an item carries its own, drawn as polygons or scan-converted.
function geometryFields() {
  if (!$('geometry-on').checked) return {};
  const rgba = [...rgbOf($('mesh-color').value), Number($('mesh-alpha').value)].map((v) => Number(v.toFixed(3))).join(',');
  const items = $('primitive').value.split(';').map((t) => t.trim()).filter((t) => t)
    .map((t) => (t.split(':').length === 2 ? `${t}:${rgba}` : t));
  const fields = { mesh_method: $('mesh-method').value };
  if ($('mesh').value) fields.mesh = `${$('mesh').value}:${rgba}`;
  if (items.length) fields.primitive = items.join(';');
  return fields;
}

function listMeshes(meshes) {
  const select = $('mesh'), chosen = select.value;
  select.replaceChildren(new Option('none', ''));
  for (const m of meshes || []) select.add(new Option(m, m));
  select.value = (meshes || []).includes(chosen) ? chosen : '';
  $('mesh-row').hidden = !(meshes && meshes.length);
}

// The cutting plane: a point and a normal, px,py,pz,nx,ny,nz.
function cutField() {
  if (!$('cut-on').checked || !state.info) return null;
  const axis = Number($('cut-axis').value);
  const point = state.info.center.slice();
  point[axis] = Number($('cut-pos').value);
  const normal = [0, 0, 0];
  normal[axis] = $('cut-flip').checked ? -1 : 1;
  return [...point, ...normal];
}

// The volume of interest: its corners x0,y0,z0,x1,y1,z1, and its opacity outside.
function voiFields() {
  if (!$('voi-on').checked || !state.info) return { voi: null };
  const lo = [0, 1, 2].map((a) => Number($(`voi-min-${a}`).value));
  const hi = [0, 1, 2].map((a) => Number($(`voi-max-${a}`).value));
  for (let a = 0; a < 3; ++a) if (hi[a] <= lo[a]) hi[a] = lo[a] + 1;
  return { voi: [...lo, ...hi], voi_outside: Number($('voi-outside').value) };
}

// ---- talking to the server ------------------------------------------------------------------
let pendingInteractive = false;

// Asks for a frame of the current state: while interacting at most one an animation frame.
function request(interacting) {
  if (!socket || socket.readyState !== WebSocket.OPEN || !state.camera) return;
  if (interacting) {
    if (pendingInteractive) return;
    pendingInteractive = true;
    requestAnimationFrame(() => { pendingInteractive = false; send(true); });
  } else {
    send(false);
  }
}

function send(interacting) {
  const size = imageSize();
  const c = state.camera;
  // The frame table's fields (the command line's flags, snake_case), as the server's info lists them.
  const message = {
    type: 'frame',
    seq: ++state.seq,
    scene: state.info.scene,  // a request of the volume shown before is dropped by the server
    interacting,
    eye: c.eye, center: c.center, up: c.up, fov: c.fov, size: [size, size],
    ...tfFields(),
    classification: $('preintegrated').checked ? 'preintegrated' : 'post',
    ...surfaceFields(),
    cut: cutField(),
    ...voiFields(),
    ...geometryFields(),
  };
  state.sent.set(message.seq, performance.now());
  if (state.sent.size > 500) state.sent.delete(state.sent.keys().next().value);
  socket.send(JSON.stringify(message));
}

let settleTimer = 0;
// Input that comes in bursts (wheel, slider drags): interactive frames, then the final one.
function burst() {
  request(true);
  clearTimeout(settleTimer);
  settleTimer = setTimeout(() => request(false), 200);
}

function connect() {
  const url = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`;
  socket = new WebSocket(url);
  socket.binaryType = 'arraybuffer';
  socket.onopen = () => setState('connected');
  socket.onclose = () => setState('disconnected');
  socket.onerror = () => setState('disconnected');
  socket.onmessage = (event) => {
    if (typeof event.data === 'string') onText(JSON.parse(event.data));
    else onFrame(event.data);
  };
}

// Every message about a volume names it: what is not about the volume shown (or being opened) is
// dropped, so one volume's state never shows under another's name.
const shown = (scene) => state.info && scene === state.info.scene;
function onText(m) {
  if (m.type === 'info') openInfo(m);
  else if (m.type === 'volumes') { listVolumes(m.volumes, m.pacs); showPacs(m.pacs); listMeshes(m.meshes); }
  else if (m.type === 'pacs') listPacs(m.series);
  else if (m.type === 'loading') onLoading(m);
  else if (m.type === 'surface') {
    if (!shown(m.scene)) return;
    if (m.state === 'ready' && state.simplifying === m.iso) state.simplifying = null;  // (told again once simplified)
    onSurface(m);
  }
  else if (m.type === 'error') {
    if (m.scene !== undefined && m.scene === state.opening) {
      // The open failed: the volume shown stays, the menu names it again, and the reason (the
      // server's words: the menu's label and the reader's error) stays until dismissed.
      state.opening = null;
      showLoading('');
      if (state.info && state.info.preview && state.info.scene === m.scene) state.info = null;  // (its preview is closed too)
      $('volumes').value = shownVolumeValue();
      if (!state.info) setState('choose a volume');
      showError(m.message, { sticky: true });
      return;
    }
    if (m.scene !== undefined && !shown(m.scene)) return;
    if (m.message.startsWith('pacs: ')) $('pacs-state').textContent = '';
    showError(m.message);
  }
}

function onLoading(m) {
  if (m.scene !== state.opening) return;
  state.loads.push({ scene: m.scene, task: m.task, progress: m.progress });
  if (state.loads.length > 1000) state.loads.shift();
  showLoading(`opening ${state.openingLabel}: ${m.task} ${Math.round(100 * m.progress)} %`);
}

// The line of the volume being opened, apart from the figures of the frame shown ('': none).
function showLoading(text) {
  $('loading').textContent = text;
  $('loading').hidden = !text;
}

async function onFrame(buffer) {
  const received = performance.now();
  const bytes = new Uint8Array(buffer);
  const headerLength = bytes[0] | (bytes[1] << 8) | (bytes[2] << 16) | (bytes[3] << 24);
  const header = JSON.parse(new TextDecoder().decode(bytes.subarray(4, 4 + headerLength)));
  if (!shown(header.scene)) return;  // a frame of the volume shown before
  // The surface's state as of this frame, before the decoding's await lets later messages in: a
  // 'ready' sent after this frame must not be undone by it.
  // (ready, the builder may still simplify it for moving frames, which draw a preview meanwhile)
  state.simplifying = header.iso !== null && header.surfaceReady && header.surfaceBuilding ? header.iso : null;
  if (header.iso !== null && header.surfaceReady) onSurface({ iso: header.iso, state: 'ready' });
  const blob = new Blob([bytes.subarray(4 + headerLength)], { type: header.format === 'png' ? 'image/png' : 'image/jpeg' });
  const bitmap = await createImageBitmap(blob);
  ctx.imageSmoothingEnabled = true;
  // Bilinear: a magnified interactive frame is 0.4 dB nearer the final image than with the cubic of 'high'.
  ctx.imageSmoothingQuality = 'low';
  ctx.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
  bitmap.close();
  const painted = performance.now();
  const sentAt = state.sent.get(header.seq);
  state.metrics.push({
    scene: header.scene, preview: header.preview, iso: header.iso, surfaceReady: header.surfaceReady, surfaceSpacing: header.surfaceSpacing, surfaceBuilding: header.surfaceBuilding, seq: header.seq, quality: header.quality, level: header.level, levelText: header.levelText,
    width: header.width, height: header.height, bytes: buffer.byteLength, renderMs: header.renderMs,
    encodeMs: header.encodeMs, waitMs: header.waitMs, paintMs: painted - received,
    // (a frame the server made without a new request, refining or after a surface came, has no arrival)
    upMs: sentAt === undefined || header.requestEpochMs === null ? null : header.requestEpochMs - (performance.timeOrigin + sentAt),
    downMs: performance.timeOrigin + received - header.sentEpochMs,
    latencyMs: sentAt === undefined ? null : painted - sentAt, paintedAt: painted, bricksNotResident: header.bricksNotResident || 0,
    textureBytes: header.textureBytes || 0,
  });
  if (state.metrics.length > 5000) state.metrics.shift();
  state.displayed = header;
  state.displayedBlob = blob;
  drawMarker(header.camera);
  const building = header.iso === null ? 'final without the surface (building)'
    : header.iso === Number($('iso').value) ? 'final with a clustered preview of the surface (building)' : `final with the surface at ${header.iso} (building)`;
  setState(header.quality === 'final' && header.surfaceReady === false ? building : header.quality);
  $('numbers').textContent = `${(header.renderMs + header.encodeMs).toFixed(0)} ms · ${(header.textureBytes / 1048576).toFixed(1)} MB · ` +
    `max error ${header.maxError.toFixed(1)}` + (header.bricksNotResident > 0 ? ` · ${header.bricksNotResident} bricks coarser` : '');
  $('level').textContent = header.levelText;
  if (header.quality === 'final') {
    state.lastFinal = { header, blob };
    $('command').value = header.command || '(the isosurface asked for is still being built)';
    const tfLink = $('save-tf');
    tfLink.hidden = !header.tfText;
    if (header.tfText) tfLink.href = URL.createObjectURL(new Blob([header.tfText], { type: 'text/plain' }));
  }
}

// ---- the orientation marker: the patient's axes as the painted frame's camera shows them -----
// (as `hybrid-octree render --marker on` draws it: L/R red, P/A green, S/I blue, far ends dimmed)
function markerLabels(camera) {
  const f = unit(sub(camera.center, camera.eye));
  const r = unit(cross(f, camera.up));
  const u = cross(r, f);
  const half = $('marker').width / 2, reach = half * 2 / 3;
  const axes = [[[1, 0, 0], 'L', 'R', [242, 77, 64]], [[0, 1, 0], 'P', 'A', [89, 217, 89]], [[0, 0, 1], 'S', 'I', [89, 140, 255]]];
  const labels = [];
  for (const [axis, plus, minus, colour] of axes)
    for (const [sign, letter] of [[1, plus], [-1, minus]]) {
      const a = mul(axis, sign);
      labels.push({ letter, colour, x: half + reach * dot(a, r), y: half - reach * dot(a, u), depth: dot(a, f) });
    }
  return labels;
}

function drawMarker(camera) {
  const marker = $('marker'), g = marker.getContext('2d'), half = marker.width / 2;
  g.clearRect(0, 0, marker.width, marker.height);
  g.font = 'bold 12px system-ui, sans-serif';
  g.textAlign = 'center';
  g.textBaseline = 'middle';
  for (const l of markerLabels(camera).sort((a, b) => b.depth - a.depth)) {  // far ends first
    const shade = l.depth > 0 ? 0.55 : 1;
    const rgb = `rgb(${l.colour.map((c) => Math.round(c * shade)).join(',')})`;
    g.strokeStyle = rgb;
    g.lineWidth = 2;
    g.beginPath();
    g.moveTo(half, half);
    g.lineTo(half + 0.72 * (l.x - half), half + 0.72 * (l.y - half));
    g.stroke();
    g.fillStyle = rgb;
    g.fillText(l.letter, l.x, l.y);
  }
}

function setState(text) {
  const el = $('state');
  el.textContent = text;
  el.className = text === 'final' ? 'final' : '';
}

// A message over the picture, with a button that dismisses it: a sticky one (why an open failed)
// stays until then, another goes after 6 s. Each replaces the last of its kind.
function showError(text, { sticky = false } = {}) {
  state.errors.push(text);
  const box = $('message'), kind = sticky ? 'sticky' : 'passing';
  let item = box.querySelector(`.${kind}`);
  if (!item) {
    item = document.createElement('div');
    item.className = `item ${kind}`;
    const close = document.createElement('button');
    Object.assign(close, { textContent: '×', title: 'dismiss' });
    close.setAttribute('aria-label', 'dismiss');
    close.addEventListener('click', () => dismissError(kind));
    item.append(document.createElement('span'), close);
    box.append(item);
  }
  item.firstChild.textContent = text;
  box.hidden = false;
  clearTimeout(item.timer);
  if (!sticky) item.timer = setTimeout(() => dismissError(kind), 6000);
}

function dismissError(kind) {
  const box = $('message'), item = box.querySelector(`.${kind}`);
  if (item) { clearTimeout(item.timer); item.remove(); }
  box.hidden = box.children.length === 0;
}

function onSurface(m) {
  state.surfaceStates[m.iso] = m.state;
  showSurfaceState();
  if (m.iso !== Number($('iso').value) || m.state !== 'building') return;
  $('surface-state').textContent = `building ${m.iso}: ${m.task || 'surface'} ${Math.round(100 * m.progress)} %`;
}

// The state of the isovalue asked for, in the volume shown.
function showSurfaceState() {
  const iso = Number($('iso').value), s = state.surfaceStates[iso];
  const ready = state.simplifying === iso ? `${iso} ready; simplifying it for moving frames` : `${iso} ready`;
  $('surface-state').textContent = !$('surface-on').checked || s === undefined ? '' : s === 'ready' ? ready : s === 'failed' ? `${iso} failed` : `building ${iso}`;
}

// ---- a volume opened ------------------------------------------------------------------------
function listVolumes(volumes, pacs) {
  const select = $('volumes');
  $('volumes-row').hidden = volumes.length === 0;
  select.replaceChildren(new Option('choose a volume…', ''));
  for (const v of volumes) select.add(new Option(v.label, JSON.stringify({ path: v.path, series: v.series })));
  if (!state.info) setState(volumes.length ? 'choose a volume' : pacs ? 'search the PACS' : 'no volumes in the data directory');
}

// ---- the PACS: searched on the server (QIDO-RS), a series opened by its address ---------------
function showPacs(pacs) {
  $('pacs').hidden = !pacs;
  if (pacs) $('pacs').querySelector('legend').textContent = `PACS ${pacs}`;
}

function listPacs(series) {
  $('pacs-state').textContent = series.length ? `${series.length} series` : 'nothing found';
  $('pacs-results').replaceChildren(...series.map((s) => {
    const item = document.createElement('li');
    const open = document.createElement('button');
    open.type = 'button';
    open.textContent = s.label;
    open.title = s.url;
    open.addEventListener('click', () => openSeries(s.url, s.label));
    item.append(open);
    return item;
  }));
}

function openSeries(url, label) {
  if (!socket) return;
  state.opening = url;  // the scene key the server gives it
  state.openingLabel = label;
  dismissError('sticky');
  socket.send(JSON.stringify({ type: 'open', url }));
  if (!state.info) setState('');
  showLoading(`opening ${label}`);
}

// The menu's value of the volume shown ('' when none is).
function shownVolumeValue() {
  const open = state.info && state.info.open;
  return open ? JSON.stringify({ path: open.path, series: open.series }) : '';
}

function cloneCamera(c) { return { eye: c.eye.slice(), center: c.center.slice(), up: c.up.slice(), fov: c.fov }; }

function openInfo(info) {
  // The scene replacing its preview keeps what the user did meanwhile: view, look, isovalue, cut.
  const upgrade = state.info && state.info.preview && !info.preview && state.info.scene === info.scene;
  state.info = info;
  state.opening = info.preview ? info.scene : null;  // a preview's progress is the scene's load
  if (!info.preview) showLoading('');
  state.opened.push({ scene: info.scene, at: performance.now(), preview: info.preview });
  state.surfaceStates = {};
  for (const iso of info.surfaces) state.surfaceStates[iso] = 'ready';
  // The name may wrap anywhere; the dimensions and the orientation never inside themselves.
  const piece = (text) => { const s = document.createElement('span'); s.className = 'nowrap'; s.textContent = text; return s; };
  $('volume-name').replaceChildren(info.name, ' · ', piece((info.preview ? 'preview ' : '') + info.dims.join('×')), ' · ',
    piece(info.orientationAssumed ? `orientation unknown: grid axes taken as ${info.orientation}` : info.orientation));
  if (upgrade) {
    const [lo, hi] = info.range;
    for (const id of ['iso', 'iso-number']) { $(id).min = Math.min(lo + 1, hi); $(id).max = hi; }
    showSurfaceState();
    setState(`opened ${info.name}`);
    request(false);
    return;
  }
  if (info.volumes) listVolumes(info.volumes, info.pacs);
  listMeshes(info.meshes);
  showPacs(info.pacs);
  $('volumes').value = shownVolumeValue();
  const presets = $('preset');
  presets.replaceChildren();
  for (const name of Object.keys(info.presets)) presets.add(new Option(name, name));
  if (!info.defaultPreset) presets.add(new Option('ramp (data range)', ''));
  setPreset(info.defaultPreset);
  const [lo, hi] = info.range;
  // A surface separates values below the isovalue from those at or above it: none at the smallest.
  for (const id of ['iso', 'iso-number']) { $(id).min = Math.min(lo + 1, hi); $(id).max = hi; }
  const iso = info.iso !== null ? info.iso : info.defaultIso;
  $('iso').value = $('iso-number').value = iso;
  // Cut and VOI sliders over the volume's patient bounds.
  const b = info.bounds;
  buildVoiSliders(b);
  setCutRange();
  state.camera = cloneCamera(info.views.anterior);
  setRanges(info.fields);
  drawTfEditor();
  showSurfaceState();
  state.opened[state.opened.length - 1].surfaceLabel = $('surface-state').textContent;  // what the page said of the surface at once
  setState(`opened ${info.name}`);
  request(false);
}

// The controls' ranges: the server's frame table's (what a frame message may hold), within the
// travel each slider is useful over (opacity beyond 3 is opaque; outside a VOI fainter, not brighter;
// an invisible surface is the checkbox's job).
function setRanges(fields) {
  const field = Object.fromEntries(fields.map((f) => [f.name, f]));
  const range = (id, name, lo, hi) => { $(id).min = Math.max(field[name].min, lo); $(id).max = Math.min(field[name].max, hi); };
  range('opacity', 'opacity', 0, 3);
  range('voi-outside', 'voi_outside', 0, 1);
  range('surface-alpha', 'surface_color', 0.05, 1);
}

function setPreset(name) {
  const points = name ? state.info.presets[name] : state.info.defaultTf;
  state.preset = name;
  state.basePoints = points.map((p) => p.slice());
  const values = points.map((p) => p[0]);
  state.baseWindow = Math.max(1e-6, Math.max(...values) - Math.min(...values));
  state.baseLevel = (Math.max(...values) + Math.min(...values)) / 2;
  state.window = state.baseWindow;
  state.level = state.baseLevel;
  state.edited = false;
  $('preset').value = name;
  showWindowLevel();
}

function showWindowLevel() {
  $('wl-value').textContent = `window ${state.window.toFixed(0)} · level ${state.level.toFixed(0)}`;
}

function setCutRange() {
  if (!state.info) return;
  const axis = Number($('cut-axis').value);
  const b = state.info.bounds;
  const pos = $('cut-pos');
  pos.min = b.min[axis];
  pos.max = b.max[axis];
  pos.value = state.info.center[axis];
  $('cut-value').textContent = `${Number(pos.value).toFixed(0)} mm`;
}

function buildVoiSliders(b) {
  const box = $('voi-axes');
  box.replaceChildren();
  const names = ['x (R→L)', 'y (A→P)', 'z (I→S)'];
  for (let a = 0; a < 3; ++a) {
    const third = (b.max[a] - b.min[a]) / 4;
    for (const [kind, value] of [['min', b.min[a] + third], ['max', b.max[a] - third]]) {
      const row = document.createElement('div');
      row.className = 'row';
      const label = document.createElement('label');
      label.textContent = kind === 'min' ? names[a] : '';
      label.htmlFor = `voi-${kind}-${a}`;
      const input = document.createElement('input');
      Object.assign(input, { type: 'range', id: `voi-${kind}-${a}`, min: b.min[a], max: b.max[a], step: 0.5, value });
      const shown = document.createElement('output');
      const show = () => { shown.textContent = `${Number(input.value).toFixed(0)} mm`; };
      input.addEventListener('input', () => {
        // A minimum past its maximum pushes it along (and the other way).
        const other = $(`voi-${kind === 'min' ? 'max' : 'min'}-${a}`);
        if (other && (kind === 'min' ? Number(input.value) > Number(other.value) : Number(input.value) < Number(other.value))) {
          other.value = input.value;
          other.dispatchEvent(new Event('voi-moved'));
        }
        show();
        if ($('voi-on').checked) burst();
      });
      input.addEventListener('voi-moved', show);
      show();
      row.append(label, input, shown);
      box.append(row);
    }
  }
}

// ---- mouse: trackball, zoom, pan, window/level ----------------------------------------------
let drag = null;

canvas.addEventListener('contextmenu', (e) => e.preventDefault());
canvas.addEventListener('pointerdown', (e) => {
  if (!state.camera) return;
  canvas.setPointerCapture(e.pointerId);
  const mode = document.querySelector('input[name=mode]:checked').value;
  const kind = e.button === 2 || e.shiftKey ? 'pan' : mode === 'wl' ? 'wl' : 'rotate';
  drag = { kind, x: e.clientX, y: e.clientY };
});
canvas.addEventListener('pointermove', (e) => {
  if (!drag) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  drag.x = e.clientX;
  drag.y = e.clientY;
  if (dx === 0 && dy === 0) return;
  const c = state.camera;
  const forward = unit(sub(c.center, c.eye));
  const right = unit(cross(forward, c.up));
  const up = cross(right, forward);
  if (drag.kind === 'rotate') {
    // The scene turns with the pointer: the camera orbits the other way about the centre.
    const angle = (Math.hypot(dx, dy) / canvas.clientHeight) * Math.PI;
    const axis = unit(add(mul(up, -dx), mul(right, -dy)));
    const offset = rotate(sub(c.eye, c.center), axis, angle);
    c.eye = add(c.center, offset);
    c.up = unit(rotate(up, axis, angle));
  } else if (drag.kind === 'pan') {
    const distance = norm(sub(c.eye, c.center));
    const mmPerPixel = (2 * distance * Math.tan((c.fov * Math.PI) / 360)) / canvas.clientHeight;
    const shift = add(mul(right, -dx * mmPerPixel), mul(up, dy * mmPerPixel));
    c.eye = add(c.eye, shift);
    c.center = add(c.center, shift);
  } else {
    // As in 3D Slicer: horizontal drags the window, vertical the level.
    state.window = Math.max(1, state.window * Math.exp(dx * 0.005));
    state.level += dy * state.window * 0.003;
    showWindowLevel();
    drawTfEditor();
  }
  request(true);
});
const endDrag = () => {
  if (!drag) return;
  drag = null;
  request(false);
};
canvas.addEventListener('pointerup', endDrag);
canvas.addEventListener('pointercancel', endDrag);
canvas.addEventListener('wheel', (e) => {
  if (!state.camera) return;
  e.preventDefault();
  const c = state.camera;
  const offset = sub(c.eye, c.center);
  c.eye = add(c.center, mul(offset, Math.exp(Math.sign(e.deltaY) * Math.min(Math.abs(e.deltaY), 200) * 0.002)));
  burst();
}, { passive: false });

// ---- the transfer-function editor: the histogram, the opacity curve, its points ------------
const tfCanvas = $('tf-editor');
const tfCtx = tfCanvas.getContext('2d');
let tfDrag = -1;

function tfRange() {
  const [lo, hi] = state.info.range;
  return [lo, hi];
}
const tfX = (v) => { const [lo, hi] = tfRange(); return ((v - lo) / (hi - lo)) * tfCanvas.width; };
const tfValue = (x) => { const [lo, hi] = tfRange(); return lo + (x / tfCanvas.width) * (hi - lo); };
const tfY = (a) => tfCanvas.height - 4 - a * (tfCanvas.height - 8);
const tfAlpha = (y) => Math.min(1, Math.max(0, (tfCanvas.height - 4 - y) / (tfCanvas.height - 8)));

function drawTfEditor() {
  if (!state.info) return;
  const w = tfCanvas.width, h = tfCanvas.height;
  tfCtx.clearRect(0, 0, w, h);
  const counts = state.info.histogram.counts;
  const top = Math.log1p(Math.max(...counts));
  tfCtx.fillStyle = '#3a3f47';
  counts.forEach((n, i) => {
    const bh = (Math.log1p(n) / top) * (h - 8);
    tfCtx.fillRect((i / counts.length) * w, h - 4 - bh, w / counts.length + 0.5, bh);
  });
  const points = currentPoints();
  // The points' own opacities (what a click sets); dashed, as scaled by the opacity slider.
  const curve = (scale) => {
    tfCtx.beginPath();
    points.forEach(([v, , , , a], i) => {
      if (i === 0) tfCtx.moveTo(tfX(v), tfY(Math.min(1, a * scale)));
      else tfCtx.lineTo(tfX(v), tfY(Math.min(1, a * scale)));
    });
    tfCtx.stroke();
  };
  tfCtx.strokeStyle = '#e8c37a';
  tfCtx.lineWidth = 1.5;
  if (state.opacity !== 1) {
    tfCtx.setLineDash([3, 3]);
    curve(state.opacity);
    tfCtx.setLineDash([]);
  }
  curve(1);
  for (const [v, r, g, b, a] of points) {
    tfCtx.fillStyle = `rgb(${r * 255}, ${g * 255}, ${b * 255})`;
    tfCtx.beginPath();
    tfCtx.arc(tfX(v), tfY(a), 4, 0, 2 * Math.PI);
    tfCtx.fill();
    tfCtx.strokeStyle = '#000';
    tfCtx.stroke();
  }
}

// Editing makes the current points the new base (window/level start again from them).
function editPoints(points) {
  state.basePoints = points;
  const values = points.map((p) => p[0]);
  state.baseWindow = state.window = Math.max(1e-6, Math.max(...values) - Math.min(...values));
  state.baseLevel = state.level = (Math.max(...values) + Math.min(...values)) / 2;
  state.edited = true;
  showWindowLevel();
  drawTfEditor();
}

function pointerInTf(e) {
  const r = tfCanvas.getBoundingClientRect();
  return [((e.clientX - r.left) / r.width) * tfCanvas.width, ((e.clientY - r.top) / r.height) * tfCanvas.height];
}
function nearestPoint(x, y) {
  let best = -1, bestD = 9;
  currentPoints().forEach(([v, , , , a], i) => {
    const d = Math.hypot(tfX(v) - x, tfY(a) - y);
    if (d < bestD) { best = i; bestD = d; }
  });
  return best;
}
tfCanvas.addEventListener('pointerdown', (e) => {
  if (!state.info || e.button !== 0) return;
  const [x, y] = pointerInTf(e);
  tfDrag = nearestPoint(x, y);
  if (tfDrag >= 0) tfCanvas.setPointerCapture(e.pointerId);
});
tfCanvas.addEventListener('pointermove', (e) => {
  if (tfDrag < 0) return;
  const [x, y] = pointerInTf(e);
  const points = currentPoints();
  const lo = tfDrag > 0 ? points[tfDrag - 1][0] : -Infinity, hi = tfDrag + 1 < points.length ? points[tfDrag + 1][0] : Infinity;
  points[tfDrag][0] = Math.min(hi, Math.max(lo, tfValue(x)));
  points[tfDrag][4] = tfAlpha(y);
  editPoints(points);
  request(true);
});
tfCanvas.addEventListener('pointerup', () => { if (tfDrag >= 0) { tfDrag = -1; request(false); } });
tfCanvas.addEventListener('dblclick', (e) => {
  if (!state.info) return;
  const [x, y] = pointerInTf(e);
  const v = tfValue(x);
  const points = currentPoints();
  let i = points.findIndex((p) => p[0] > v);
  if (i < 0) i = points.length;
  const near = points[Math.min(i, points.length - 1)];
  points.splice(i, 0, [v, near[1], near[2], near[3], tfAlpha(y)]);
  if (points.length <= 64) { editPoints(points); request(false); }
});
tfCanvas.addEventListener('contextmenu', (e) => {
  e.preventDefault();
  if (!state.info) return;
  const [x, y] = pointerInTf(e);
  const i = nearestPoint(x, y);
  const points = currentPoints();
  if (i >= 0 && points.length > 2) { points.splice(i, 1); editPoints(points); request(false); }
});

// ---- controls -------------------------------------------------------------------------------
for (const b of document.querySelectorAll('#views button[data-view]'))
  b.addEventListener('click', () => { if (state.info) { state.camera = cloneCamera(state.info.views[b.dataset.view]); request(false); } });
$('reset').addEventListener('click', () => {
  if (!state.info) return;
  state.camera = cloneCamera(state.info.views.anterior);
  setPreset(state.info.defaultPreset);
  state.opacity = 1;
  $('opacity').value = 1;
  $('opacity-value').textContent = '1.00';
  drawTfEditor();
  request(false);
});
$('preset').addEventListener('change', () => { setPreset($('preset').value); drawTfEditor(); request(false); });
$('opacity').addEventListener('input', () => {
  state.opacity = Number($('opacity').value);
  $('opacity-value').textContent = state.opacity.toFixed(2);
  drawTfEditor();
  burst();
});
$('preintegrated').addEventListener('change', () => request(false));
$('size').addEventListener('change', () => {
  const s = imageSize();
  canvas.width = canvas.height = s;
  canvas.style.setProperty('--size', `${s}px`);  // its shown size (viewer.css)
  request(false);
});
$('surface-on').addEventListener('change', () => { showSurfaceState(); request(false); });
$('iso').addEventListener('input', () => { $('iso-number').value = $('iso').value; });
$('iso').addEventListener('change', () => { showSurfaceState(); request(false); });
$('iso-number').addEventListener('change', () => {
  const typed = $('iso-number').value, v = Number(typed);
  if (typed.trim() === '' || !Number.isFinite(v)) {
    showError(typed.trim() === '' ? 'isovalue: expected a number' : `isovalue: '${typed}' is not a number`);
    $('iso-number').value = $('iso').value;  // the surface shown stays
    return;
  }
  $('iso').value = v;  // clamped to the data's range and rounded to the slider's step
  if (Number($('iso').value) !== v) showError(`isovalue ${typed}: a surface needs ${$('iso').min} to ${$('iso').max} in steps of 1: using ${$('iso').value}`);
  $('iso-number').value = $('iso').value;
  showSurfaceState();
  request(false);
});
$('surface-color').addEventListener('input', () => burst());
$('surface-alpha').addEventListener('input', () => burst());
$('cut-on').addEventListener('change', () => request(false));
$('cut-axis').addEventListener('change', () => { setCutRange(); request(false); });
$('cut-flip').addEventListener('change', () => request(false));
$('cut-pos').addEventListener('input', () => { $('cut-value').textContent = `${Number($('cut-pos').value).toFixed(0)} mm`; if ($('cut-on').checked) burst(); });
$('voi-on').addEventListener('change', () => request(false));
for (const id of ['geometry-on', 'mesh', 'mesh-method', 'primitive']) $(id).addEventListener('change', () => request(false));
for (const id of ['mesh-color', 'mesh-alpha']) $(id).addEventListener('input', () => { if ($('geometry-on').checked) burst(); });
$('voi-outside').addEventListener('input', () => { if ($('voi-on').checked) burst(); });
$('volumes').addEventListener('change', () => {
  const select = $('volumes');
  if (!select.value || !socket) {
    select.value = shownVolumeValue();
    return;
  }
  const open = JSON.parse(select.value);
  state.opening = open.series ? `${open.path}#${open.series}` : open.path;  // the scene key the server gives it
  state.openingLabel = select.selectedOptions[0].textContent;
  dismissError('sticky');  // (a failed open's reason: the user has moved on)
  socket.send(JSON.stringify({ type: 'open', ...open }));
  if (!state.info) setState('');
  showLoading(`opening ${state.openingLabel}`);
});
$('pacs-search').addEventListener('submit', (event) => {
  event.preventDefault();
  if (!socket) return;
  $('pacs-state').textContent = 'searching…';
  socket.send(JSON.stringify({ type: 'pacs-search', patient: $('pacs-patient').value.trim(), study_date: $('pacs-date').value.trim(),
                               modality: $('pacs-modality').value.trim() }));
});
$('save-png').addEventListener('click', () => {
  const save = (blob) => {
    const a = document.createElement('a');
    a.href = URL.createObjectURL(blob);
    a.download = 'view.png';
    a.click();
  };
  if (state.lastFinal) save(state.lastFinal.blob);
  else canvas.toBlob(save, 'image/png');
});
for (const [id, format] of [['save-ply', 'ply'], ['save-stl', 'stl']])
  $(id).addEventListener('click', (e) => {
    if (!state.info || !$('surface-on').checked) { e.preventDefault(); showError('turn the isosurface on first'); return; }
    $(id).href = `/api/mesh?iso=${encodeURIComponent($('iso').value)}&format=${format}&scene=${encodeURIComponent(state.info.scene)}`;
    $(id).download = `surface-${$('iso').value}.${format}`;
  });
$('copy-command').addEventListener('click', async () => {
  const text = $('command').value;
  try { await navigator.clipboard.writeText(text); } catch { $('command').select(); document.execCommand('copy'); }
});

async function base64(blob) {
  const bytes = new Uint8Array(await blob.arrayBuffer());
  let s = '';
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

// For tests and benchmarks: what was painted, and ways to wait for it.
window.hybViewer = {
  state,
  metrics: () => state.metrics.slice(),
  request,
  lastFinal: () => state.lastFinal && state.lastFinal.header,
  tfPoints: () => currentPoints(),
  loads: () => state.loads.slice(),
  opened: () => state.opened.slice(),
  surfaceLabel: () => $('surface-state').textContent,
  marker: () => state.displayed && markerLabels(state.displayed.camera),
  // What the canvas shows now: the header of the frame painted last, the canvas as PNG and the
  // frame as it came, decoded at its own size, as PNG (base64).
  async snapshot() {
    const header = state.displayed, png = canvas.toDataURL('image/png');
    const bitmap = await createImageBitmap(state.displayedBlob);
    const own = new OffscreenCanvas(bitmap.width, bitmap.height);
    own.getContext('2d').drawImage(bitmap, 0, 0);
    return { header, png, frame: await base64(await own.convertToBlob({ type: 'image/png' })) };
  },
  async lastFinalPng() {
    if (!state.lastFinal) return null;
    return base64(state.lastFinal.blob);
  },
};

connect();
