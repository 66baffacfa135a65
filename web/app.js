// The viewer page: upload a mesh through the public API, follow the job's events, then
// show the rigged GLB with its skeleton, a bone's weights as a heat map and a test motion.
//
// Tests read `window.rigserveViewer` (state, jobId, bones drawn, playing, …) rather than
// pixels; everything in it is what the page itself shows.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { swayClip } from './motion.js';

const $ = (id) => document.getElementById(id);
const STAGES = ['validating', 'encoding', 'skeleton', 'skinning', 'exporting'];
const CONTENT_TYPES = {
  glb: 'model/gltf-binary',
  vrm: 'model/gltf-binary',
  gltf: 'model/gltf+json',
  obj: 'model/obj',
};

const viewer = {
  state: 'idle', // idle | uploading | queued | running | loading | ready | failed
  jobId: null,
  stage: null,
  progress: 0,
  stagesSeen: [],
  bones: 0, // bones the skeleton overlay draws
  joints: 0, // joints of the loaded skin
  clip: null,
  playing: false,
  selectedBone: -1,
  frames: 0,
  error: null,
};
window.rigserveViewer = viewer;

// ---------------------------------------------------------------------------------------
// Scene

const canvas = $('canvas');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x2b3038);
const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 1000);
camera.position.set(0, 1.5, 4);
const controls = new OrbitControls(camera, canvas);
scene.add(new THREE.HemisphereLight(0xffffff, 0x444444, 2));
const sun = new THREE.DirectionalLight(0xffffff, 2);
sun.position.set(2, 4, 3);
scene.add(sun);
const grid = new THREE.GridHelper(10, 20, 0x555555, 0x3a3a3a);
scene.add(grid);

const clock = new THREE.Clock();
let model = null; // { root, skinned: SkinnedMesh[], bones: Bone[], tree, mixer, action, overlay }

function resize() {
  const { clientWidth: w, clientHeight: h } = canvas.parentElement;
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(h, 1);
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

renderer.setAnimationLoop(() => {
  const dt = clock.getDelta();
  if (model) {
    if (viewer.playing) model.mixer.update(dt);
    model.root.updateMatrixWorld(true);
    updateOverlay(model);
  }
  controls.update();
  renderer.render(scene, camera);
  viewer.frames += 1;
});

// ---------------------------------------------------------------------------------------
// Upload and job events

const form = $('upload');
const fileInput = $('file');
const drop = $('drop');
let chosen = null;

function choose(file) {
  chosen = file;
  $('drop-text').textContent = file ? `${file.name} (${(file.size / 1024).toFixed(0)} KiB)` : '';
  $('submit').disabled = !file;
}
fileInput.addEventListener('change', () => choose(fileInput.files[0] || null));
drop.addEventListener('dragover', (e) => { e.preventDefault(); drop.classList.add('over'); });
drop.addEventListener('dragleave', () => drop.classList.remove('over'));
drop.addEventListener('drop', (e) => {
  e.preventDefault();
  drop.classList.remove('over');
  if (e.dataTransfer.files.length) choose(e.dataTransfer.files[0]);
});

function setState(state, text) {
  viewer.state = state;
  const el = $('status');
  el.textContent = text || state;
  el.classList.toggle('failed', state === 'failed');
}

function fail(message) {
  viewer.error = message;
  setState('failed', `failed: ${message}`);
  $('submit').disabled = !chosen;
}

function showStages() {
  $('stages').replaceChildren(...STAGES.map((s) => {
    const li = document.createElement('li');
    li.textContent = s;
    const at = viewer.stagesSeen.indexOf(s);
    if (at >= 0 && (s !== viewer.stage || viewer.state !== 'running')) li.className = 'done';
    if (s === viewer.stage && viewer.state === 'running') li.textContent += ' …';
    return li;
  }));
}

form.addEventListener('submit', async (e) => {
  e.preventDefault();
  if (!chosen) return;
  const data = new FormData(form);
  const query = new URLSearchParams();
  for (const key of ['category', 'template', 'seed', 'samples', 'max_bones']) {
    const v = String(data.get(key) ?? '').trim();
    if (v !== '' && !(key === 'template' && v === 'auto')) query.set(key, v);
  }
  query.set('animation', data.get('animation') ? 'preview' : 'none');
  const ext = chosen.name.split('.').pop().toLowerCase();

  $('submit').disabled = true;
  $('job').hidden = false;
  $('result').hidden = true;
  Object.assign(viewer, { jobId: null, stage: null, progress: 0, stagesSeen: [], error: null });
  showStages();
  setState('uploading');
  let job;
  try {
    const r = await fetch(`/v1/jobs?${query}`, {
      method: 'POST',
      headers: { 'content-type': CONTENT_TYPES[ext] || 'application/octet-stream' },
      body: chosen,
    });
    const body = await r.json();
    if (!r.ok) return fail(`${body.error} (${body.error_type})`);
    job = body;
  } catch (err) {
    return fail(String(err));
  }
  viewer.jobId = job.id;
  setState('queued', `job ${job.id}: queued`);
  follow(job.id);
});

function follow(id) {
  // The server ends the stream after a terminal event; closing then keeps EventSource
  // from reconnecting, and its own reconnects (with Last-Event-ID) cover drops before.
  const es = new EventSource(`/v1/jobs/${id}/events`);
  es.addEventListener('job', (msg) => {
    const ev = JSON.parse(msg.data);
    viewer.progress = ev.progress;
    $('progress').value = ev.progress;
    if (ev.stage && !viewer.stagesSeen.includes(ev.stage)) viewer.stagesSeen.push(ev.stage);
    viewer.stage = ev.stage;
    if (ev.status === 'queued' || ev.status === 'running') {
      setState(ev.status, `job ${id}: ${ev.status}${ev.stage ? ` (${ev.stage})` : ''}`);
    } else {
      es.close();
      if (ev.status === 'succeeded') {
        $('progress').value = 1;
        loadResult(id);
      } else {
        fail(ev.error ? `${ev.error.message} (${ev.error.code})` : ev.status);
      }
    }
    showStages();
  });
}

// ---------------------------------------------------------------------------------------
// Result

async function loadResult(id) {
  setState('loading', `job ${id}: loading the result`);
  const glbUrl = `/v1/jobs/${id}/result.glb`;
  const treeUrl = `/v1/jobs/${id}/skeleton.json`;
  try {
    const [gltf, tree] = await Promise.all([
      new GLTFLoader().loadAsync(glbUrl),
      fetch(treeUrl).then((r) => (r.ok ? r.json() : Promise.reject(new Error(`skeleton.json: ${r.status}`)))),
    ]);
    show(gltf, tree);
  } catch (err) {
    return fail(String(err));
  }
  $('download-glb').href = glbUrl;
  $('download-glb').download = `${id}.glb`;
  $('download-skeleton').href = treeUrl;
  $('download-skeleton').download = `${id}.skeleton.json`;
  $('result').hidden = false;
  setState('ready', `job ${id}: done`);
}

function show(gltf, tree) {
  if (model) {
    scene.remove(model.root, model.overlay.lines, model.overlay.points);
    model.mixer.stopAllAction();
  }
  const root = gltf.scene;
  const skinned = [];
  root.traverse((o) => { if (o.isSkinnedMesh) skinned.push(o); });
  if (!skinned.length) throw new Error('the GLB has no skinned mesh');
  // Joint k of every rigserve skin is bone k of the tree.
  const bones = skinned[0].skeleton.bones;
  if (bones.length !== tree.bones.length) {
    throw new Error(`the skin has ${bones.length} joints, the bone tree ${tree.bones.length} bones`);
  }
  for (const m of skinned) {
    m.userData.material = m.material;
    m.frustumCulled = false; // posed vertices can leave the rest-pose bounds
  }
  scene.add(root);

  const mixer = new THREE.AnimationMixer(root);
  const baked = gltf.animations.find((a) => a.name === 'rigserve_preview');
  const clip = baked || swayClip(tree, bones);
  const action = mixer.clipAction(clip);
  action.play();
  mixer.update(0);

  const overlay = makeOverlay(tree.bones.length);
  scene.add(overlay.lines, overlay.points);
  model = { root, skinned, bones, tree, mixer, action, overlay };
  Object.assign(viewer, {
    joints: bones.length,
    clip: baked ? clip.name : `${clip.name} (built in the page)`,
    playing: false,
    selectedBone: -1,
  });
  $('play').textContent = 'Play motion';
  root.updateMatrixWorld(true);
  updateOverlay(model);
  viewer.bones = overlay.drawn;
  frame(root);
  fillBoneList(tree);
  $('summary').textContent = `${tree.bones.length} bones, ${skinned.length} skinned mesh${skinned.length > 1 ? 'es' : ''}, motion: ${viewer.clip}`;
}

function frame(root) {
  const box = new THREE.Box3().setFromObject(root);
  const size = box.getSize(new THREE.Vector3()).length() || 1;
  const center = box.getCenter(new THREE.Vector3());
  controls.target.copy(center);
  camera.position.copy(center).add(new THREE.Vector3(0.35, 0.25, 1).normalize().multiplyScalar(size * 1.4));
  camera.near = size / 1000;
  camera.far = size * 100;
  camera.updateProjectionMatrix();
  grid.position.y = box.min.y;
  grid.scale.setScalar(size / 4);
}

// ---------------------------------------------------------------------------------------
// Skeleton overlay: one segment per bone, head to tail, drawn over the mesh.

function makeOverlay(n) {
  const positions = new THREE.BufferAttribute(new Float32Array(n * 6), 3);
  const colors = new THREE.BufferAttribute(new Float32Array(n * 6), 3);
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', positions);
  geometry.setAttribute('color', colors);
  const lines = new THREE.LineSegments(
    geometry,
    new THREE.LineBasicMaterial({ vertexColors: true, depthTest: false, transparent: true }),
  );
  const heads = new THREE.BufferGeometry();
  heads.setAttribute('position', new THREE.BufferAttribute(new Float32Array(n * 3), 3));
  const points = new THREE.Points(
    heads,
    new THREE.PointsMaterial({ color: 0xffd24a, size: 6, sizeAttenuation: false, depthTest: false, transparent: true }),
  );
  lines.renderOrder = points.renderOrder = 10;
  lines.frustumCulled = points.frustumCulled = false;
  return { lines, points, drawn: 0 };
}

const _head = new THREE.Vector3();
const _tail = new THREE.Vector3();

function updateOverlay(m) {
  const { tree, bones, overlay } = m;
  const pos = overlay.lines.geometry.attributes.position;
  const col = overlay.lines.geometry.attributes.color;
  const heads = overlay.points.geometry.attributes.position;
  let drawn = 0;
  tree.bones.forEach((b, i) => {
    // A rigserve joint's rest frame is a translation to its head, so the tail in the
    // bone's local frame is tail - head; the posed bone matrix carries it along.
    const world = bones[i].matrixWorld;
    _head.setFromMatrixPosition(world);
    _tail.set(b.tail[0] - b.head[0], b.tail[1] - b.head[1], b.tail[2] - b.head[2]).applyMatrix4(world);
    pos.setXYZ(2 * i, _head.x, _head.y, _head.z);
    pos.setXYZ(2 * i + 1, _tail.x, _tail.y, _tail.z);
    heads.setXYZ(i, _head.x, _head.y, _head.z);
    // Saturated cyan (red for the selected bone) stands out from any heat-map colour.
    const c = i === viewer.selectedBone ? [1, 0.05, 0.05] : [0, 0.8, 1];
    col.setXYZ(2 * i, ...c);
    col.setXYZ(2 * i + 1, ...c);
    drawn += 1;
  });
  pos.needsUpdate = col.needsUpdate = heads.needsUpdate = true;
  overlay.drawn = drawn;
}

$('show-skeleton').addEventListener('change', (e) => {
  if (!model) return;
  model.overlay.lines.visible = model.overlay.points.visible = e.target.checked;
});

// ---------------------------------------------------------------------------------------
// Heat map of one bone's weights

function fillBoneList(tree) {
  const select = $('bone');
  select.replaceChildren(new Option('(no heat map)', '-1'));
  tree.bones.forEach((b, i) => select.add(new Option(b.name, String(i))));
}

// Blue (0) through green to red (1).
function heat(w, out) {
  out.setHSL((1 - Math.min(Math.max(w, 0), 1)) * (2 / 3), 1, 0.5);
  return out;
}

function showWeights(bone) {
  viewer.selectedBone = bone;
  const c = new THREE.Color();
  for (const m of model.skinned) {
    if (bone < 0) {
      m.material = m.userData.material;
      continue;
    }
    const g = m.geometry;
    const idx = g.attributes.skinIndex;
    const wts = g.attributes.skinWeight;
    const colors = new Float32Array(idx.count * 3);
    for (let v = 0; v < idx.count; v++) {
      let w = 0;
      for (let k = 0; k < 4; k++) if (idx.getComponent(v, k) === bone) w += wts.getComponent(v, k);
      heat(w, c).toArray(colors, v * 3);
    }
    g.setAttribute('color', new THREE.BufferAttribute(colors, 3));
    m.material = new THREE.MeshLambertMaterial({ vertexColors: true });
  }
}

$('bone').addEventListener('change', (e) => model && showWeights(Number(e.target.value)));

// ---------------------------------------------------------------------------------------
// Motion

function setPlaying(on) {
  viewer.playing = on;
  $('play').textContent = on ? 'Pause motion' : 'Play motion';
  clock.getDelta();
}

$('play').addEventListener('click', () => model && setPlaying(!viewer.playing));

// Seconds into the clip, for tests and the curious.
Object.defineProperty(viewer, 'time', { get: () => (model ? model.action.time : 0), enumerable: true });
