// faceanim view: the page. Loads /api/info and /model, shows the model with an orbit camera,
// a slider per morph target (grouped as the server says), the animations with their sound, and
// a panel to pick points on the mesh or a photo and save them as the JSON faceanim reads.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { DRACOLoader } from 'three/addons/loaders/DRACOLoader.js';
import { MeshoptDecoder } from 'three/addons/libs/meshopt_decoder.module.js';
import { RoomEnvironment } from 'three/addons/environments/RoomEnvironment.js';

const $ = (id) => document.getElementById(id);

// What tests and benchmarks read (and the bench's per-frame hook); the page works without it.
const viewer = {
  ready: false, error: null, info: null, renders: 0, morphCount: 0, vertexCount: 0,
  bindings: new Map(),          // morph name -> [{mesh, index}]
  onFrame: [],                  // callbacks (t seconds) run before each render
  points: { mesh: [], photos: [] },
};
window.viewer = viewer;

function fail(message) {
  viewer.error = message;
  const b = $('banner');
  b.textContent = message;
  b.hidden = false;
  console.error('faceanim view: ' + message);
}

// ------------------------------------------------------------------------------------ scene
// WebGL drawn by the CPU (SwiftShader, llvmpipe: no GPU) gets the fast look unless ?quality=high:
// no multisampling, no environment map, Lambert shading (3-4x the frame rate there)
function softwareRenderer() {
  try {
    const gl = document.createElement('canvas').getContext('webgl2');
    const ext = gl.getExtension('WEBGL_debug_renderer_info');
    const name = String(gl.getParameter(ext ? ext.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    const lose = gl.getExtension('WEBGL_lose_context');
    if (lose) lose.loseContext();
    return /swiftshader|llvmpipe|softpipe|software/i.test(name) ? name : '';
  } catch (e) {
    return '';
  }
}
const software = softwareRenderer();
const quality = new URLSearchParams(location.search).get('quality') || (software ? 'fast' : 'high');
const fast = quality === 'fast';
viewer.quality = quality;
const canvas = $('view');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: !fast });
viewer.renderer = renderer;
renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
renderer.toneMapping = THREE.NeutralToneMapping;
const scene = new THREE.Scene();
viewer.scene = scene;
scene.background = new THREE.Color(0x30343c);
const camera = new THREE.PerspectiveCamera(30, 1, 0.01, 100);
viewer.camera = camera;
const controls = new OrbitControls(camera, canvas);
controls.enableDamping = false;
if (!fast) {
  const pmrem = new THREE.PMREMGenerator(renderer);
  scene.environment = pmrem.fromScene(new RoomEnvironment(), 0.04).texture;
  scene.environmentIntensity = 0.55;
} else {
  scene.add(new THREE.AmbientLight(0xffffff, 0.9));
}
const key = new THREE.DirectionalLight(0xffffff, 1.6);
key.position.set(0.6, 0.8, 1.0);
const fill = new THREE.DirectionalLight(0xffffff, 0.5);
fill.position.set(-0.8, 0.1, 0.6);
scene.add(key, fill, new THREE.HemisphereLight(0xffffff, 0x404040, 0.4));
camera.add(new THREE.PointLight(0xffffff, 0));  // keeps the camera in the graph for lights that follow it
scene.add(camera);

let dirty = true;
const requestRender = () => { dirty = true; };
viewer.requestRender = requestRender;
controls.addEventListener('change', requestRender);

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (!w || !h) return;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  requestRender();
}
new ResizeObserver(resize).observe(canvas);

let root = null;       // the model's scene
let vrm = null;        // three-vrm's VRM, for a .vrm
const restMatrix = new Map();  // mesh -> its matrix relative to the model root as loaded
let markerSize = 0.003;
const markers = new THREE.Group();
scene.add(markers);

// ------------------------------------------------------------------------------------ morphs
const sliders = new Map();  // name -> {input, output, row, kind}

function weightOf(name) {
  const b = viewer.bindings.get(name);
  return b && b.length ? b[0].mesh.morphTargetInfluences[b[0].index] : 0;
}

// a VRM's expression manager rewrites the morph weights of the meshes its expressions bind on every
// update: weights set on morph targets directly are kept here and set again after each update
const direct = new Map();  // morph name -> weight, for a .vrm

function setWeight(name, value) {
  if (name.startsWith('vrm:')) {
    vrm.expressionManager.setValue(name.slice(4), value);
  } else {
    for (const { mesh, index } of viewer.bindings.get(name) || []) mesh.morphTargetInfluences[index] = value;
    if (vrm) direct.set(name, value);
  }
  requestRender();
}

function reapplyDirect() {
  for (const [name, value] of direct) {
    for (const { mesh, index } of viewer.bindings.get(name) || []) mesh.morphTargetInfluences[index] = value;
  }
}
viewer.setWeight = setWeight;
viewer.weight = weightOf;

function addSlider(container, name, label, min) {
  const row = document.createElement('div');
  row.className = 'slider';
  row.dataset.name = name;
  const id = 'w-' + sliders.size;
  const lab = document.createElement('label');
  lab.htmlFor = id;
  lab.textContent = label;
  lab.title = label;
  const input = document.createElement('input');
  Object.assign(input, { type: 'range', id, min: String(min), max: '1', step: '0.01', value: '0' });
  input.dataset.name = name;
  const out = document.createElement('output');
  out.textContent = '0.00';
  input.addEventListener('input', () => {
    pauseIfPlaying();
    setWeight(name, parseFloat(input.value));
    out.textContent = parseFloat(input.value).toFixed(2);
  });
  row.append(lab, input, out);
  container.append(row);
  sliders.set(name, { input, output: out, row });
}

function buildSliders(groups) {
  const box = $('groups');
  box.textContent = '';
  const shown = new Set();
  const all = [...groups];
  const missing = [...viewer.bindings.keys()].filter((n) => !groups.some((g) => g.names.includes(n)));
  if (missing.length) all.push({ set: 'other', label: 'Other', names: missing });
  let count = 0;
  for (const g of all) {
    const names = g.names.filter((n) => viewer.bindings.has(n) && !shown.has(n));
    if (!names.length) continue;
    const det = document.createElement('details');
    det.open = count === 0 || viewer.bindings.size <= 60;  // many targets: the first set open
    det.dataset.set = g.set;
    const sum = document.createElement('summary');
    sum.textContent = `${g.label} (${names.length})`;
    det.append(sum);
    for (const n of names) {
      addSlider(det, n, n, g.set === 'fap' || g.set === 'other' ? -1 : 0);
      shown.add(n);
      count += 1;
    }
    box.append(det);
  }
  if (vrm && vrm.expressionManager) {
    const det = document.createElement('details');
    det.open = true;
    det.dataset.set = 'vrm';
    const names = vrm.expressionManager.expressions.map((e) => e.expressionName);
    const sum = document.createElement('summary');
    sum.textContent = `VRM expressions (${names.length})`;
    det.append(sum);
    for (const n of names) addSlider(det, 'vrm:' + n, n, 0);
    if (names.length) box.append(det);
  }
  $('morph-count').textContent = `(${count})`;
}

function syncSliders() {
  for (const [name, s] of sliders) {
    const v = name.startsWith('vrm:') ? vrm.expressionManager.getValue(name.slice(4)) : weightOf(name);
    s.input.value = String(v);
    s.output.textContent = v.toFixed(2);
  }
}

$('filter').addEventListener('input', () => {
  const q = $('filter').value.trim().toLowerCase();
  for (const [name, s] of sliders) s.row.classList.toggle('hidden', q !== '' && !name.toLowerCase().includes(q));
});
$('reset').addEventListener('click', () => {
  pauseIfPlaying();
  for (const name of sliders.keys()) setWeight(name, 0);
  syncSliders();
});

// ------------------------------------------------------------------------------------ animation
let mixer = null, action = null, clips = [];
let playing = false, playStart = 0, playFrom = 0;
const sound = { buffer: null, ctx: null, source: null, offset: null };

function clipTime() { return action ? action.time : 0; }
viewer.clipTime = clipTime;
viewer.playing = () => playing;
viewer.sound = sound;

function applyTime(t) {
  if (!action) return;
  action.time = t;
  mixer.update(0);
  requestRender();
}

function showTime() {
  const d = action ? action.getClip().duration : 0;
  $('time').textContent = `${clipTime().toFixed(2)} / ${d.toFixed(2)} s`;
  $('scrub').value = String(clipTime());
}

function startSound(t) {
  stopSound();
  if (!sound.buffer || t >= sound.buffer.duration) return;
  try {
    if (!sound.ctx) sound.ctx = new AudioContext();
    if (sound.ctx.state === 'suspended') sound.ctx.resume();
    const src = sound.ctx.createBufferSource();
    src.buffer = sound.buffer;
    src.connect(sound.ctx.destination);
    src.start(0, t);
    sound.source = src;
    sound.offset = t;
  } catch (e) {
    console.warn('faceanim view: no sound: ' + e);
  }
}

function stopSound() {
  if (sound.source) {
    try { sound.source.stop(); } catch (e) { /* already stopped */ }
    sound.source.disconnect();
  }
  sound.source = null;
  sound.offset = null;
}

function play() {
  if (!action) return;
  const d = action.getClip().duration;
  if (clipTime() >= d - 1e-3) applyTime(0);
  playing = true;
  playFrom = clipTime();
  playStart = performance.now() / 1000;
  startSound(playFrom);
  $('play').textContent = 'Pause';
}

function pause() {
  playing = false;
  stopSound();
  $('play').textContent = 'Play';
  syncSliders();
  showTime();
}
function pauseIfPlaying() { if (playing) pause(); }
viewer.play = play;
viewer.pause = pause;

function tick(now) {
  if (!playing || !action) return;
  const d = action.getClip().duration;
  let t = playFrom + (now - playStart);
  if (t >= d) {
    if ($('loop').checked && d > 0) {
      t %= d;
      playFrom = t;
      playStart = now;
      startSound(t);
    } else {
      applyTime(d);
      pause();
      return;
    }
  }
  applyTime(t);
}

function setupAnimations(gltfAnimations) {
  clips = gltfAnimations || [];
  if (!clips.length) return;
  mixer = new THREE.AnimationMixer(root);
  const sel = $('clip');
  clips.forEach((c, k) => {
    const o = document.createElement('option');
    o.value = String(k);
    o.textContent = `${c.name || 'animation ' + (k + 1)} (${c.duration.toFixed(2)} s)`;
    sel.append(o);
  });
  sel.hidden = clips.length < 2;
  selectClip(0);
  $('anim-section').hidden = false;
  $('play').addEventListener('click', () => (playing ? pause() : play()));
  sel.addEventListener('change', () => { pauseIfPlaying(); selectClip(parseInt(sel.value, 10)); });
  $('scrub').addEventListener('input', () => {
    pauseIfPlaying();
    applyTime(parseFloat($('scrub').value));
    syncSliders();
    showTime();
  });
}

function selectClip(k) {
  if (action) action.stop();
  action = mixer.clipAction(clips[k]);
  action.setLoop(THREE.LoopOnce, 1);
  action.clampWhenFinished = true;
  action.play();
  action.paused = true;  // the page sets its time (applyTime); the mixer never advances it
  $('scrub').max = String(clips[k].duration);
  showTime();
}

async function loadSound(info) {
  if (!info.sound) { $('sound').textContent = 'no sound'; return; }
  try {
    const data = await (await fetch(info.sound.url)).arrayBuffer();
    const ctx = new OfflineAudioContext(1, 1, 44100);
    sound.buffer = await ctx.decodeAudioData(data);
    $('sound').textContent = `sound: ${info.sound.name} (${sound.buffer.duration.toFixed(2)} s), in sync`;
  } catch (e) {
    $('sound').textContent = `sound ${info.sound.name} could not be decoded`;
    console.warn('faceanim view: ' + e);
  }
}

// ------------------------------------------------------------------------------------ points
const pickTarget = $('pick-target');
const photoView = $('photo-view');
const img = $('photo');
let photoIndex = -1;  // shown photo, -1: the mesh
const VIEWS = ['front', 'side', 'side2'];

function say(msg, bad) {
  const s = $('save-status');
  s.textContent = msg;
  s.style.color = bad ? '#ff8080' : '';
}

function landmarkIndex(name) {
  const named = viewer.info.names.landmarks;
  if (Object.prototype.hasOwnProperty.call(named, name)) return named[name];
  const m = /^mp:?(\d{1,3})$/.exec(name);
  return m && +m[1] < 478 ? +m[1] : undefined;
}

function photoNameOk(name) {
  const n = viewer.info.names;
  return n.fdp.includes(name) || n.photo_extra.includes(name) || (/^mp:\d{1,3}$/.test(name) && +name.slice(3) < 478);
}

function takeName() {
  const input = $('point-name');
  const name = input.value.trim();
  input.value = '';
  return name;
}

function addMeshPoint(name, rest, world) {
  const list = viewer.points.mesh;
  const index = landmarkIndex(name);
  for (let k = list.length - 1; k >= 0; k--) {
    if (list[k].name === name || (index !== undefined && list[k].index === index)) {
      markers.remove(list[k].marker);
      list.splice(k, 1);
    }
  }
  const marker = new THREE.Mesh(new THREE.SphereGeometry(markerSize, 12, 8),
    new THREE.MeshBasicMaterial({ color: 0xffd400, depthTest: true }));
  marker.position.copy(world);
  markers.add(marker);
  list.push({ name, index, position: rest.toArray(), marker });
  renderPoints();
  requestRender();
}

function pickMesh(ev) {
  const r = canvas.getBoundingClientRect();
  const ndc = new THREE.Vector2(((ev.clientX - r.left) / r.width) * 2 - 1, -((ev.clientY - r.top) / r.height) * 2 + 1);
  const ray = new THREE.Raycaster();
  ray.setFromCamera(ndc, camera);
  const hits = ray.intersectObject(root, true).filter((h) => h.object.isMesh && h.face && restMatrix.has(h.object));
  if (!hits.length) { say('no surface under the pointer'); return; }
  const h = hits[0], m = h.object, f = h.face;
  // the hit's barycentric coordinates on the triangle as shown (morphs applied) ...
  const shownCorners = [f.a, f.b, f.c].map((i) => m.getVertexPosition(i, new THREE.Vector3()).applyMatrix4(m.matrixWorld));
  const bary = THREE.Triangle.getBarycoord(h.point, ...shownCorners, new THREE.Vector3());
  if (!bary) { say('could not place the point; try again'); return; }
  // ... put on the same triangle at rest, in the model's own coordinates (as in the file)
  const pos = m.geometry.attributes.position;
  const rest = new THREE.Vector3();
  [f.a, f.b, f.c].forEach((i, k) => {
    rest.addScaledVector(new THREE.Vector3().fromBufferAttribute(pos, i), bary.getComponent(k));
  });
  rest.applyMatrix4(restMatrix.get(m));
  const name = takeName() || nextName();
  addMeshPoint(name, rest, h.point);
  say(`${name}: ${rest.toArray().map((x) => x.toFixed(4)).join(', ')}`);
}

function nextName() {
  let k = 1;
  while (viewer.points.mesh.some((p) => p.name === 'p' + k)) k++;
  return 'p' + k;
}

function pickPhoto(ev) {
  const r = img.getBoundingClientRect();
  const x = ((ev.clientX - r.left) / r.width) * img.naturalWidth;
  const y = ((ev.clientY - r.top) / r.height) * img.naturalHeight;
  const name = $('point-name').value.trim();
  if (!name) { say('type the point\'s name first (an FDP such as 9.3, mp:N, head_top, head_back)', true); return; }
  if (!photoNameOk(name)) {
    say(`'${name}' is not a point faceanim photo knows: an FDP such as 9.3, mp:N (0..477), head_top or head_back`, true);
    return;
  }
  takeName();
  const pts = viewer.points.photos[photoIndex].points;
  pts[name] = [Math.round(x * 100) / 100, Math.round(y * 100) / 100];
  renderPoints();
  say(`${name}: ${pts[name][0].toFixed(1)}, ${pts[name][1].toFixed(1)} px`);
}

function renderPoints() {
  const ol = $('point-list');
  ol.textContent = '';
  const marks = $('photo-marks');
  marks.textContent = '';
  const entries = photoIndex < 0
    ? viewer.points.mesh.map((p) => [p.name, p.position.map((x) => x.toFixed(4)).join(', ')])
    : Object.entries(viewer.points.photos[photoIndex].points).map(([n, xy]) => [n, `${xy[0].toFixed(1)}, ${xy[1].toFixed(1)} px`]);
  for (const [name, text] of entries) {
    const li = document.createElement('li');
    li.textContent = `${name}  (${text})`;
    const del = document.createElement('button');
    del.type = 'button';
    del.textContent = 'x';
    del.title = 'remove';
    del.addEventListener('click', () => removePoint(name));
    li.append(del);
    ol.append(li);
  }
  if (photoIndex >= 0 && img.naturalWidth) {
    for (const [name, [x, y]] of Object.entries(viewer.points.photos[photoIndex].points)) {
      const d = document.createElement('div');
      d.className = 'mark';
      d.style.left = `${(100 * x) / img.naturalWidth}%`;
      d.style.top = `${(100 * y) / img.naturalHeight}%`;
      const s = document.createElement('span');
      s.textContent = name;
      d.append(s);
      marks.append(d);
    }
  }
}

function removePoint(name) {
  if (photoIndex < 0) {
    const list = viewer.points.mesh;
    const k = list.findIndex((p) => p.name === name);
    if (k >= 0) { markers.remove(list[k].marker); list.splice(k, 1); }
    requestRender();
  } else {
    delete viewer.points.photos[photoIndex].points[name];
  }
  renderPoints();
}

function setupPoints(info) {
  const dl = $('point-names');
  const names = [...Object.keys(info.names.landmarks), ...info.names.fdp, ...info.names.photo_extra];
  for (const n of names) {
    const o = document.createElement('option');
    o.value = n;
    dl.append(o);
  }
  info.photos.forEach((p, k) => {
    viewer.points.photos.push({ view: VIEWS[k] || 'front', points: {} });
    const o = document.createElement('option');
    o.value = String(k);
    o.textContent = `photo: ${p.name}`;
    pickTarget.append(o);
  });
  pickTarget.addEventListener('change', () => showTarget(pickTarget.value === 'mesh' ? -1 : parseInt(pickTarget.value, 10)));
  photoView.addEventListener('change', () => { viewer.points.photos[photoIndex].view = photoView.value; });
  img.addEventListener('load', () => { fitPhoto(); renderPoints(); });
  new ResizeObserver(fitPhoto).observe($('photo-pane'));
  img.addEventListener('click', pickPhoto);
  let down = null;
  canvas.addEventListener('pointerdown', (ev) => { down = [ev.clientX, ev.clientY]; });
  canvas.addEventListener('pointerup', (ev) => {
    if (down && ev.button === 0 && Math.hypot(ev.clientX - down[0], ev.clientY - down[1]) < 4) pickMesh(ev);
    down = null;
  });
  $('save').addEventListener('click', save);
  $('clear').addEventListener('click', () => {
    if (photoIndex < 0) { viewer.points.mesh.forEach((p) => markers.remove(p.marker)); viewer.points.mesh = []; }
    else viewer.points.photos[photoIndex].points = {};
    renderPoints();
    requestRender();
  });
  if (info.save_points) say(`Save writes ${info.save_points} (and downloads a copy)`);
  else say('Save downloads the points (start with --save-points PATH to write a file)');
}

function fitPhoto() {
  // the photo as large as the pane allows (small photos scaled up: finer picking)
  const pane = $('photo-pane');
  if (!img.naturalWidth || !pane.clientWidth) return;
  const s = Math.min((pane.clientWidth - 20) / img.naturalWidth, (pane.clientHeight - 20) / img.naturalHeight);
  img.style.width = `${Math.floor(img.naturalWidth * s)}px`;
  img.style.height = `${Math.floor(img.naturalHeight * s)}px`;
}

function showTarget(k) {
  photoIndex = k;
  $('photo-pane').hidden = k < 0;
  $('hint').hidden = k >= 0;
  photoView.hidden = k < 0;
  if (k >= 0) {
    photoView.value = viewer.points.photos[k].view;
    const url = viewer.info.photos[k].url;
    if (!img.src.endsWith(url)) img.src = url;
  }
  renderPoints();
  requestRender();
}

function landmarksJson() {
  return {
    scheme: 'custom',
    points: viewer.points.mesh.map((p) => (p.index === undefined
      ? { name: p.name, position: p.position } : { name: p.name, index: p.index, position: p.position })),
  };
}

function photoJson() {
  const data = {}, views = {};
  viewer.points.photos.forEach((ph, k) => {
    if (!Object.keys(ph.points).length) return;
    if (views[ph.view] !== undefined) throw new Error(`two photos are marked '${ph.view}'; give each its own view`);
    views[ph.view] = k;
    data[ph.view] = { ...ph.points };
  });
  return { data, views };
}
viewer.landmarksJson = landmarksJson;
viewer.photoJson = photoJson;

async function save() {
  let body, file;
  try {
    if (photoIndex < 0) {
      if (!viewer.points.mesh.length) { say('pick a point on the mesh first', true); return; }
      body = { kind: 'landmarks', data: landmarksJson() };
      file = 'landmarks.json';
    } else {
      const { data, views } = photoJson();
      if (!Object.keys(data).length) { say('pick a point on the photo first', true); return; }
      body = { kind: 'photo', data, views };
      file = 'points.json';
    }
  } catch (e) { say(e.message, true); return; }
  const text = JSON.stringify(body.data, null, 1) + '\n';
  let answer;
  try {
    const r = await fetch('/api/points', { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
    answer = await r.json();
    if (!r.ok) { say(answer.error || `not saved (${r.status})`, true); return; }
  } catch (e) {
    say('the viewer is not running (faceanim view stopped?); not saved', true);
    return;
  }
  const a = document.createElement('a');
  a.href = URL.createObjectURL(new Blob([text], { type: 'application/json' }));
  a.download = file;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
  say(answer.saved ? `saved to ${answer.saved} (and downloaded ${file})` : `downloaded ${file}; ${answer.message}`);
  viewer.lastSaved = answer;
}

// ------------------------------------------------------------------------------------ loading
function frame(box) {
  const size = box.getSize(new THREE.Vector3());
  const centre = box.getCenter(new THREE.Vector3());
  const span = Math.max(size.x, size.y, 1e-6);
  const dist = (span / 2) / Math.tan(THREE.MathUtils.degToRad(camera.fov / 2)) * 1.15 + size.z / 2;
  camera.position.set(centre.x, centre.y, centre.z + dist);
  camera.near = dist / 100;
  camera.far = dist * 100;
  camera.updateProjectionMatrix();
  controls.target.copy(centre);
  controls.update();
  markerSize = span * 0.008;
}

viewer.project = (points) => {
  // model coordinates -> CSS pixels in the page
  const r = canvas.getBoundingClientRect();
  return points.map((p) => {
    const v = new THREE.Vector3(...p);
    if (root) v.applyMatrix4(root.matrixWorld);
    v.project(camera);
    return [r.left + ((v.x + 1) / 2) * r.width, r.top + ((1 - v.y) / 2) * r.height];
  });
};

async function main() {
  const res = await fetch('/api/info');
  if (!res.ok) throw new Error(`the server answered ${res.status} for /api/info`);
  const info = await res.json();
  viewer.info = info;
  $('model-name').textContent = `${info.model.name} (${info.model.kind.toUpperCase()}, ${(info.model.size / 1048576).toFixed(1)} MB)`;
  document.title = `${info.model.name} - faceanim view`;

  const loader = new GLTFLoader();
  const draco = new DRACOLoader();
  draco.setDecoderPath('/vendor/three/examples/jsm/libs/draco/gltf/');
  loader.setDRACOLoader(draco);
  loader.setMeshoptDecoder(MeshoptDecoder);
  let VRMUtils = null;
  if (info.model.kind === 'vrm') {
    const mod = await import('@pixiv/three-vrm');
    VRMUtils = mod.VRMUtils;
    loader.register((parser) => new mod.VRMLoaderPlugin(parser));
  }
  const gltf = await loader.loadAsync(info.model.url);
  root = gltf.scene;
  root.updateMatrixWorld(true);
  let vertices = 0;
  root.traverse((o) => {
    if (!o.isMesh) return;
    restMatrix.set(o, o.matrixWorld.clone());
    vertices += o.geometry.attributes.position.count;
    o.frustumCulled = false;  // morphs move vertices outside the rest bounds
    const dict = o.morphTargetDictionary;
    if (!dict) return;
    for (const [name, index] of Object.entries(dict)) {
      if (!viewer.bindings.has(name)) viewer.bindings.set(name, []);
      viewer.bindings.get(name).push({ mesh: o, index });
    }
  });
  if (fast) {
    root.traverse((o) => {
      const m = o.material;
      if (!o.isMesh || !m || Array.isArray(m) || !(m.isMeshStandardMaterial || m.isMeshPhysicalMaterial)) return;
      o.material = new THREE.MeshLambertMaterial({
        map: m.map, color: m.color, side: m.side, transparent: m.transparent, opacity: m.opacity,
        alphaTest: m.alphaTest, normalMap: m.normalMap, emissive: m.emissive, emissiveMap: m.emissiveMap,
        vertexColors: m.vertexColors, name: m.name,
      });
    });
  }
  viewer.vertexCount = vertices;
  viewer.morphCount = viewer.bindings.size;
  if (gltf.userData.vrm) {
    vrm = gltf.userData.vrm;
    VRMUtils.rotateVRM0(vrm);
    root = vrm.scene;
  }
  scene.add(root);
  root.updateMatrixWorld(true);
  const box = new THREE.Box3().setFromObject(root);
  const head = vrm && vrm.humanoid && vrm.humanoid.getNormalizedBoneNode('head');
  if (head && box.getSize(new THREE.Vector3()).y > 0.6) {
    // a full-body avatar: frame its head
    const c = head.getWorldPosition(new THREE.Vector3());
    frame(new THREE.Box3().setFromCenterAndSize(c.add(new THREE.Vector3(0, 0.04, 0)), new THREE.Vector3(0.3, 0.3, 0.25)));
  } else {
    frame(box);
  }
  $('model-stats').textContent = `${vertices.toLocaleString('en')} vertices, ${viewer.morphCount} morph targets, ` +
    `${gltf.animations.length} animation${gltf.animations.length === 1 ? '' : 's'}` +
    (fast ? '; fast shading (?quality=high for the full look)' : '');
  buildSliders(info.groups);
  setupAnimations(gltf.animations);
  setupPoints(info);
  await loadSound(info);
  resize();
  if (info.live) startLive(info.live);
  viewer.ready = true;
}

// ------------------------------------------------------------------------------------ live
// faceanim live --to viewer: ARKit curves over a WebSocket, applied by name as they arrive
const live = { messages: 0, skipped: 0, latencies: [], connected: false, closed: false, pending: null, apply: null };
window.faceanimLive = live;

function nameKey(name) {
  // eyeBlink_L, EyeBlinkLeft, eye_blink_left, eyeBlinkL -> eyeblinkleft
  // as faceanim.io.arkit_csv.name_key: a trailing L/R after a separator or a lower-case letter is the side
  return name.trim().replace(/(?:[._\s-]|(?<=[a-z]))L$/, 'Left').replace(/(?:[._\s-]|(?<=[a-z]))R$/, 'Right')
    .toLowerCase().replace(/[^a-z0-9]/g, '');
}

function liveTargets(names) {
  // per ARKit curve: the avatar's morph targets or VRM expressions of that name (any spelling)
  const byKey = new Map();
  if (vrm && vrm.expressionManager) {
    for (const e of vrm.expressionManager.expressions) byKey.set(nameKey(e.expressionName), 'vrm:' + e.expressionName);
  }
  for (const n of viewer.bindings.keys()) if (!byKey.has(nameKey(n))) byKey.set(nameKey(n), n);
  const presets = { eyeBlinkLeft: 'blinkLeft', eyeBlinkRight: 'blinkRight', jawOpen: 'aa' };
  return names.map((n) => byKey.get(nameKey(n)) || (vrm && presets[n] && byKey.get(nameKey(presets[n]))) || null);
}

function startLive(spec) {
  const targets = liveTargets(spec.names);
  live.matched = targets.filter((t) => t).length;
  const box = new THREE.Box3().setFromObject(root);
  const pivot = box.getCenter(new THREE.Vector3());
  // the head bone: a VRM's normalised humanoid head (its rest is the identity, its axes the
  // model's), else a bone named as a head's (the server's faceanim.avatar.HEAD_BONE_NAMES): turned
  // in the model's axes through its parents' rotations from its rest; with neither, the model turns
  const headNames = spec.headBones || [];
  let headBone = vrm && vrm.humanoid && vrm.humanoid.getNormalizedBoneNode('head');
  let above = null;
  let rest = null;
  if (!headBone) {
    root.traverse((o) => { if (!headBone && o.isBone && headNames.includes(o.name.trim().toLowerCase())) headBone = o; });
    if (headBone) {
      above = headBone.parent ? headBone.parent.getWorldQuaternion(new THREE.Quaternion()) : new THREE.Quaternion();
      rest = headBone.quaternion.clone();
    }
  }
  live.turned = headBone ? headBone.name || 'head' : 'model';
  const restWorld = headBone ? headBone.getWorldQuaternion(new THREE.Quaternion()) : null;
  const nowWorld = new THREE.Quaternion();
  live.headTurn = 0;  // radians the head bone's world rotation is from its rest (what tests read)
  const euler = new THREE.Euler(0, 0, 0, 'YXZ');
  const q = new THREE.Quaternion();
  const ws = new WebSocket(spec.url);
  ws.onopen = () => { live.connected = true; say(`live: ${live.matched} of ${spec.names.length} ARKit curves drive this avatar`); };
  ws.onclose = () => { live.closed = true; };
  ws.onmessage = (ev) => {
    // only the newest frame is drawn: one that arrives while the page draws replaces the one before
    if (live.pending) live.skipped += 1;
    live.pending = ev.data;
    live.messages += 1;
    dirty = true;
  };
  live.apply = () => {
    const m = JSON.parse(live.pending);
    live.pending = null;
    for (let k = 0; k < targets.length; k += 1) if (targets[k]) setWeight(targets[k], m.w[k]);
    euler.set(m.h[1], m.h[0], m.h[2], 'YXZ');  // pitch about x, yaw about y, roll about z
    q.setFromEuler(euler);
    if (headBone && rest) {
      headBone.quaternion.copy(above).invert().multiply(q).multiply(above).multiply(rest);  // P^-1 D P R
    } else if (headBone) {
      headBone.quaternion.copy(q);
    }
    if (headBone) {
      live.headTurn = headBone.getWorldQuaternion(nowWorld).angleTo(restWorld);
    } else {
      root.quaternion.copy(q);
      root.position.copy(pivot).sub(pivot.clone().applyQuaternion(q));
    }
    live.latencies.push(performance.timeOrigin + performance.now() - m.c);
    if (live.latencies.length > 5000) live.latencies.shift();
  };
}

let last = performance.now() / 1000;
function loop(ms) {
  const now = ms / 1000;
  const dt = Math.min(now - last, 0.1);
  last = now;
  if (playing) {
    tick(performance.now() / 1000);
    showTime();
    if (viewer.renders % 6 === 0) syncSliders();
  }
  for (const f of viewer.onFrame) f(now);
  if (live.pending) live.apply();
  if (vrm) { vrm.update(dt); reapplyDirect(); dirty = true; }
  if (dirty || playing || viewer.onFrame.length) {
    dirty = false;
    renderer.render(scene, camera);
    viewer.renders += 1;
  }
  requestAnimationFrame(loop);
}

main().then(() => requestAnimationFrame(loop)).catch((e) => fail(`could not load the model: ${e.message || e}`));
