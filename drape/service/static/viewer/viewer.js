// drape viewer: rig an outfit (POST /v1/outfits/rig, multipart), animate it (POST /v1/outfits/animate,
// Accept: model/gltf-binary) and play the GLB with three.js: body and garment, orbit controls, play/pause and
// a frame slider. Or two garments worn together (a combination of GET /v1/layers): POST /v1/layers/animate's
// GLB (both layers as one vertex-animated mesh, inner first), the inner layer orange, the outer blue. Or a garment
// template of the intrinsic space (GET /v1/garments, models "intrinsic") from one keyframe: a design drawn by
// POST /v1/garments/{name}/sample (the design number is its seed), its latent the keyframe at frame 0 of
// POST /v1/garments/{name}/animate's GLB (a vertex-animated mesh). The motion is an embedded clip or an uploaded
// mocap file (a CMU-named BVH or an AMASS-style npz: the routes' multipart `motion_file`, imported at 30 fps).
// Every address is relative to /viewer/, so the page works under any prefix.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const API = new URL('../v1/', window.location.href);
const $ = (id) => document.getElementById(id);
// what the page is doing, for people and for tests
const state = window.drapeViewer = {ready: false, loaded: false, playing: false, frame: 0, frames: 0,
  framesRendered: 0, error: null, webgl: null, layers: null, keyframed: null};
const motions = new Map();
const combinations = new Map();  // "layers:<inner>:<outer>" -> GET /v1/layers entry + the inner's vertex count
const templates = new Map();  // "intrinsic:<name>" -> GET /v1/garments entry of a template with an intrinsic model

// ---- the service ---------------------------------------------------------------------------------------

function withKey(headers = {}) {
  const key = $('key').value.trim();
  return key ? {...headers, authorization: `Bearer ${key}`} : headers;
}

async function api(path, init = {}) {
  const r = await fetch(new URL(path, API), {...init, headers: withKey(init.headers)});
  if (!r.ok) {
    let detail = r.statusText;
    try { const p = await r.json(); detail = `${p.title || ''}: ${p.detail || ''}`; } catch { /* not a problem document */ }
    throw new Error(`${r.status} ${detail}${r.status === 401 ? '\nType the API key above.' : ''}`);
  }
  return r;
}

function say(text, error = false) {
  $('status').textContent = text;
  $('status').className = error ? 'error' : '';
  state.error = error ? text : null;
}

function option(select, value, text) {
  const o = document.createElement('option');
  o.value = value;
  o.textContent = text;
  select.append(o);
}

async function loadCatalogue() {
  try {
    const [bodies, clips, layers, garments] = await Promise.all(['bodies', 'motions', 'layers', 'garments'].map(
      (path) => api(path).then((r) => r.json())));
    $('body').replaceChildren();
    for (const b of bodies.bodies) option($('body'), b.name, `${b.name} (${(b.height).toFixed(2)} m)`);
    $('body').value = bodies.bodies.some((b) => b.name === 'neutral') ? 'neutral' : bodies.bodies[0].name;
    $('clip').replaceChildren();
    motions.clear();
    for (const m of clips.motions) {
      motions.set(m.name, m);
      option($('clip'), m.name, `${m.name} (${m.frames} frames)`);
    }
    option($('clip'), 'file', 'upload a mocap file (BVH, AMASS npz)…');
    if (motions.has('walk')) $('clip').value = 'walk';
    for (const old of $('outfit').querySelectorAll('optgroup')) old.remove();
    combinations.clear();
    if (layers.layers.length) {
      const group = document.createElement('optgroup');
      group.label = 'two garments worn together';
      const sizes = new Map(garments.garments.map((g) => [g.name, g.num_vertices]));
      for (const c of layers.layers) {
        const value = `layers:${c.inner}:${c.outer}`;
        combinations.set(value, {...c, innerVertices: sizes.get(c.inner)});
        option(group, value, `${c.inner} under ${c.outer} (${c.model})`);
      }
      $('outfit').append(group);
    }
    templates.clear();
    const intrinsic = garments.garments.filter((g) => g.models.includes('intrinsic'));
    if (intrinsic.length) {
      const group = document.createElement('optgroup');
      group.label = 'a garment from one keyframe';
      for (const g of intrinsic) {
        const value = `intrinsic:${g.name}`;
        templates.set(value, g);
        option(group, value, `${g.name}, a sampled design (intrinsic ${g.version})`);
      }
      $('outfit').append(group);
    }
    state.ready = true;
    $('play').disabled = false;
    say('Pick a body, an outfit and a motion, then Play.');
  } catch (e) {
    say(`Could not read the catalogue: ${e.message}`, true);
  }
}

// The outfit_id of a rig answer in npz: numpy's uncompressed zip, member outfit_id.npy (a unicode scalar).
function npzMember(buffer, name) {
  const dv = new DataView(buffer);
  const bytes = new Uint8Array(buffer);
  let end = -1;
  for (let i = buffer.byteLength - 22; i >= Math.max(0, buffer.byteLength - 65557); i--) {
    if (dv.getUint32(i, true) === 0x06054b50) { end = i; break; }
  }
  if (end < 0) throw new Error('the rig answer is not an npz archive');
  const count = dv.getUint16(end + 10, true);
  let p = dv.getUint32(end + 16, true);
  for (let k = 0; k < count && dv.getUint32(p, true) === 0x02014b50; k++) {
    const nameLength = dv.getUint16(p + 28, true);
    const entry = new TextDecoder().decode(bytes.subarray(p + 46, p + 46 + nameLength));
    if (entry === `${name}.npy`) {
      if (dv.getUint16(p + 10, true) !== 0) throw new Error(`${name}: a compressed member`);
      const local = dv.getUint32(p + 42, true);
      const start = local + 30 + dv.getUint16(local + 26, true) + dv.getUint16(local + 28, true);
      return bytes.subarray(start, start + dv.getUint32(p + 20, true));
    }
    p += 46 + nameLength + dv.getUint16(p + 30, true) + dv.getUint16(p + 32, true);
  }
  throw new Error(`no ${name} in the rig answer`);
}

function npyText(npy) {
  const dv = new DataView(npy.buffer, npy.byteOffset, npy.byteLength);
  const headerStart = npy[6] === 1 ? 10 : 12;
  const headerLength = npy[6] === 1 ? dv.getUint16(8, true) : dv.getUint32(8, true);
  const header = new TextDecoder().decode(npy.subarray(headerStart, headerStart + headerLength));
  const m = /'descr':\s*'([<>|=]?)U(\d+)'/.exec(header);
  if (!m) throw new Error('outfit_id is not text');
  let text = '';
  for (let i = 0; i < Number(m[2]); i++) {
    const c = dv.getUint32(headerStart + headerLength + 4 * i, m[1] !== '>');
    if (c === 0) break;
    text += String.fromCodePoint(c);
  }
  return text;
}

async function outfitMesh() {
  const choice = $('outfit').value;
  if (choice === 'file') {
    const file = $('mesh').files[0];
    if (!file) throw new Error('Choose a mesh file (OBJ, PLY, GLB or glTF).');
    return [file, file.name];
  }
  const r = await fetch(`outfits/${choice}.obj`);
  if (!r.ok) throw new Error(`${r.status}: no generated ${choice}`);
  return [await r.blob(), `${choice}.obj`];
}

function chosenLayers() {
  return combinations.get($('outfit').value) || null;
}

function chosenTemplate() {
  return templates.get($('outfit').value) || null;
}

// The chosen motion: {clip, name} of an embedded clip, or {file, name} of an uploaded mocap file.
function chosenMotion() {
  if ($('clip').value !== 'file') return {clip: $('clip').value, name: $('clip').value};
  const file = $('motionFile').files[0];
  if (!file) throw new Error('Choose a mocap file (a CMU-named BVH or an AMASS-style npz).');
  return {file, name: file.name};
}

// A garment or layers route's body: JSON with the clip, or a multipart form with the file and the rest of the
// request as JSON text in `request`.
function motionBody(request, motion) {
  if (motion.clip) return {body: JSON.stringify({...request, motion: {clip: motion.clip}}),
    headers: {'content-type': 'application/json'}};
  const form = new FormData();
  form.append('motion_file', motion.file, motion.file.name);
  form.append('request', JSON.stringify(request));
  return {body: form, headers: {}};
}

async function playKeyframed(g) {
  const motion = chosenMotion();
  const clip = motion.name;
  const seed = Math.max(0, Math.round(Number($('design').value) || 0));
  say(`Drawing design ${seed} of the ${g.name}…`);
  const t0 = performance.now();
  const sample = await api(`garments/${g.name}/sample`, {method: 'POST',
    ...motionBody({count: 1, seed, frame: 0}, motion)});
  const latent = (await sample.json()).latents[0];
  say(`Animating the ${g.name} along ${clip}${$('refine').checked ? ' with refinement' : ''}…`);
  const request = motionBody({keyframes: [{frame: 0, latent}], refine: $('refine').checked}, motion);
  const answer = await api(`garments/${g.name}/animate`, {method: 'POST', body: request.body,
    headers: {...request.headers, accept: 'model/gltf-binary'}});
  const glb = await answer.arrayBuffer();
  await show(glb, motions.get(clip));
  state.keyframed = {garment: g.name, design: seed, version: g.version};
  say(`${g.name} (intrinsic ${g.version}), design ${seed}, ${clip}: ${state.frames} frames, ` +
      `${(glb.byteLength / 2 ** 20).toFixed(1)} MB GLB in ${((performance.now() - t0) / 1000).toFixed(1)} s.\n` +
      'One keyframe at frame 0; another design number draws another garment. Drag to orbit, scroll to zoom.');
}

async function playLayers(c) {
  const motion = chosenMotion();
  const clip = motion.name;
  const thickness = Number($('thickness').value) / 1000;
  say(`Animating ${c.inner} under ${c.outer} along ${clip}${$('refine').checked ? ' with refinement' : ''}…`);
  const t0 = performance.now();
  const request = motionBody({inner: c.inner, outer: c.outer, thickness, refine: $('refine').checked}, motion);
  const answer = await api('layers/animate', {method: 'POST', body: request.body,
    headers: {...request.headers, accept: 'model/gltf-binary'}});
  const glb = await answer.arrayBuffer();
  await show(glb, motions.get(clip), c);
  state.layers = {inner: c.inner, outer: c.outer, model: c.model, thickness};
  say(`${c.inner} under ${c.outer} (${c.model}), ${clip}: ${state.frames} frames, ` +
      `${(glb.byteLength / 2 ** 20).toFixed(1)} MB GLB in ${((performance.now() - t0) / 1000).toFixed(1)} s.\n` +
      'Inner layer orange, outer blue. Drag to orbit, scroll to zoom.');
}

async function play() {
  $('play').disabled = true;
  try {
    state.layers = null;
    state.keyframed = null;
    const layers = chosenLayers();
    if (layers) {
      await playLayers(layers);
      return;
    }
    const template = chosenTemplate();
    if (template) {
      await playKeyframed(template);
      return;
    }
    say('Rigging the outfit…');
    const [mesh, fileName] = await outfitMesh();
    const form = new FormData();
    form.append('mesh', mesh, fileName);
    form.append('body', $('body').value);
    const rig = await api('outfits/rig', {method: 'POST', body: form, headers: {accept: 'application/x-npz'}});
    const outfitId = npyText(npzMember(await rig.arrayBuffer(), 'outfit_id'));
    const motion = chosenMotion();
    const clip = motion.name;
    say(`Animating ${clip}${$('refine').checked ? ' with refinement' : ''}…`);
    const t0 = performance.now();
    let body = JSON.stringify({outfit_id: outfitId, motion: {clip}, refine: $('refine').checked});
    let headers = {'content-type': 'application/json', accept: 'model/gltf-binary'};
    if (motion.file) {  // the upload form: motion_file, outfit_id, refine
      body = new FormData();
      body.append('motion_file', motion.file, motion.file.name);
      body.append('outfit_id', outfitId);
      body.append('refine', String($('refine').checked));
      headers = {accept: 'model/gltf-binary'};
    }
    const answer = await api('outfits/animate', {method: 'POST', headers, body});
    const glb = await answer.arrayBuffer();
    await show(glb, motions.get(clip));
    say(`${clip}: ${state.frames} frames, ${(glb.byteLength / 2 ** 20).toFixed(1)} MB GLB in ` +
        `${((performance.now() - t0) / 1000).toFixed(1)} s.\nDrag to orbit, scroll to zoom.`);
  } catch (e) {
    say(e.message, true);
  } finally {
    $('play').disabled = false;
  }
}

// ---- the scene ----------------------------------------------------------------------------------------

const canvas = $('view');
let renderer;
try {
  renderer = new THREE.WebGLRenderer({canvas, antialias: true});
  const gl = renderer.getContext();
  state.webgl = gl.getParameter(gl.VERSION);
} catch (e) {
  say(`This browser cannot draw WebGL: ${e.message}`, true);
  throw e;
}
renderer.setPixelRatio(window.devicePixelRatio);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xeef0f4);
scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8f99, 2.2));
const sun = new THREE.DirectionalLight(0xffffff, 2.0);
sun.position.set(2, 4, 3);
scene.add(sun);
const grid = new THREE.GridHelper(20, 40, 0x9aa1ad, 0xc9cdd5);
scene.add(grid);
const camera = new THREE.PerspectiveCamera(35, 1, 0.05, 100);
camera.position.set(0, 1.2, 4.2);
const controls = new OrbitControls(camera, canvas);
controls.target.set(0, 0.95, 0);
controls.enableDamping = true;

const materials = {
  body: new THREE.MeshStandardMaterial({color: 0xc8b5a6, roughness: 0.75}),
  outfit: new THREE.MeshStandardMaterial({color: 0x3a6fc0, roughness: 0.65, side: THREE.DoubleSide}),
  layers: new THREE.MeshStandardMaterial({vertexColors: true, roughness: 0.65, side: THREE.DoubleSide}),
};
const INNER_COLOUR = new THREE.Color(0xd9733a);
const OUTER_COLOUR = new THREE.Color(0x3a6fc0);
const loader = new GLTFLoader();
let model = null;
let mixer = null;
let action = null;
let root = null;
let fps = 30;
const followed = new THREE.Vector3();

// Two layers as one mesh: the first `innerVertices` vertices are the inner layer's.
function colourLayers(geometry, innerVertices) {
  const n = geometry.attributes.position.count;
  const colours = new Float32Array(3 * n);
  for (let i = 0; i < n; i++) (i < innerVertices ? INNER_COLOUR : OUTER_COLOUR).toArray(colours, 3 * i);
  geometry.setAttribute('color', new THREE.BufferAttribute(colours, 3));
}

async function show(buffer, clip, layers = null) {
  const gltf = await loader.parseAsync(buffer, '');
  if (model) {
    scene.remove(model);
    model.traverse((o) => { if (o.isMesh) o.geometry.dispose(); });
  }
  model = gltf.scene;
  root = null;
  model.traverse((o) => {
    if (!o.isMesh) return;
    o.frustumCulled = false;  // the bounds of the rest pose do not follow the motion
    o.geometry.computeVertexNormals();
    o.material = materials[o.name] || materials.outfit;
    if (layers) colourLayers(o.geometry, layers.innerVertices);
    if (o.isSkinnedMesh && !root) root = o.skeleton.bones[0];
  });
  scene.add(model);
  // A one-frame answer (a single pose) has nothing to play: a vertex animation then has no animation, a skinned
  // one a clip of duration 0 (its pose, set once below; advancing it would take the time to NaN).
  const animation = gltf.animations[0] || null;
  const moving = Boolean(animation && animation.duration > 0);
  mixer = new THREE.AnimationMixer(model);
  action = animation ? mixer.clipAction(animation) : null;
  if (action) action.play();
  fps = clip ? clip.fps : 30;
  state.frames = clip ? clip.frames : (moving ? Math.round(animation.duration * fps) + 1 : 1);
  const slider = $('frame');
  slider.max = String(state.frames - 1);
  slider.disabled = !moving;
  $('pause').disabled = !moving;
  mixer.update(0);
  model.updateMatrixWorld(true);
  if (root) {  // look at the body from the front (+Z), and follow its root from here on
    root.getWorldPosition(followed);
    controls.target.set(followed.x, 0.95, followed.z);
    camera.position.set(followed.x + 0.6, 1.35, followed.z + 4.2);
  } else {  // a vertex animation (no skeleton): look at where its first frame (the base positions) is
    let centre = new THREE.Vector3(0, 0.95, 0);
    model.traverse((o) => {
      if (o.isMesh) centre = new THREE.Box3().setFromBufferAttribute(o.geometry.attributes.position)
        .applyMatrix4(o.matrixWorld).getCenter(new THREE.Vector3());
    });
    controls.target.copy(centre);
    camera.position.set(centre.x + 0.6, centre.y + 0.4, centre.z + 4.2);  // room for a walk towards the camera
  }
  setPlaying(moving);
  showFrame();
  state.loaded = true;
}

function setPlaying(playing) {
  state.playing = playing;
  $('pause').textContent = playing ? 'Pause' : 'Play';
}

function showFrame() {
  const frame = Math.min(state.frames - 1, Math.max(0, Math.round((action ? action.time : 0) * fps)));
  state.frame = frame;
  $('frame').value = String(frame);
  $('frameLabel').textContent = `${frame} / ${state.frames - 1}`;
}

$('pause').addEventListener('click', () => setPlaying(!state.playing));
$('frame').addEventListener('input', () => {
  if (!action) return;
  setPlaying(false);
  action.time = Number($('frame').value) / fps;
  mixer.update(0);
  showFrame();
});
$('play').addEventListener('click', play);
$('outfit').addEventListener('change', () => {
  $('mesh').hidden = $('outfit').value !== 'file';
  const c = chosenLayers();
  $('thicknessLabel').hidden = !c;
  $('designLabel').hidden = !chosenTemplate();
  $('body').disabled = Boolean(c || chosenTemplate());  // the templates are dressed on their own body
  if (c) {
    const [low, high] = c.thickness.map((m) => m * 1000);
    $('thickness').min = String(low);
    $('thickness').max = String(high);
    $('thickness').value = String(Math.min(high, Math.max(low, Number($('thickness').value) || 6)));
  }
});
$('clip').addEventListener('change', () => { $('motionFile').hidden = $('clip').value !== 'file'; });
$('key').addEventListener('change', loadCatalogue);

function resize() {
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  if (canvas.width !== Math.floor(w * renderer.getPixelRatio()) || canvas.height !== Math.floor(h * renderer.getPixelRatio())) {
    renderer.setSize(w, h, false);
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
  }
}

const here = new THREE.Vector3();
let last = performance.now();
renderer.setAnimationLoop((now) => {
  const dt = Math.min(0.1, (now - last) / 1000);
  last = now;
  resize();
  if (action && state.playing) {
    mixer.update(dt);
    showFrame();
  }
  if (root) {  // the camera moves with the body's root (walks leave the start)
    root.getWorldPosition(here);
    const step = here.clone().sub(followed).setY(0);
    camera.position.add(step);
    controls.target.add(step);
    followed.copy(here);
  }
  controls.update();
  renderer.render(scene, camera);
  if (state.loaded) state.framesRendered += 1;
});

loadCatalogue();
