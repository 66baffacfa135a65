#!/usr/bin/env node
// Loads rigserve GLBs with three.js (the viewer's vendored copy, in headless Chromium),
// poses them, and reports the skinned vertex positions three.js computes
// (SkinnedMesh.getVertexPosition), for tests/viewer/deform.rs to compare with rigserve's
// own linear blend skinning and with Blender.
//
// Usage: node tools/three_deform.mjs BASE_URL JOBS.json OUT.json
// JOBS.json: [{"url": "/v1/jobs/…/result.glb", "bone": 3, "rotation": [x, y, z, w]}
//             | {"url": …, "time": 0.5}, …]
// A bone job turns joint `bone` by `rotation` (about its head, in its parent's frame,
// which for rigserve's translation-only joints at rest is the glTF world frame); a time
// job plays the `rigserve_preview` clip to that time. OUT.json gets, per job:
// {"joints", "skinned_meshes", "clips", "rest": [[x, y, z]…], "posed": […]}, positions in
// the glTF world frame, vertices in accessor order, skinned meshes in scene order.
import { readFileSync, writeFileSync } from 'node:fs';
import { launch, watchErrors } from './browser.mjs';

const [base, jobsPath, outPath] = process.argv.slice(2);
if (!base || !jobsPath || !outPath) {
  console.error('usage: node tools/three_deform.mjs BASE_URL JOBS.json OUT.json');
  process.exit(2);
}
const jobs = JSON.parse(readFileSync(jobsPath, 'utf8'));

const browser = await launch();
let results;
let errors = [];
try {
  const page = await browser.newPage();
  errors = watchErrors(page);
  // The page carries the import map the vendored three.js addons rely on.
  await page.goto(`${base}/`);
  results = await page.evaluate(async (jobs) => {
    const THREE = await import('/assets/vendor/three/build/three.module.js');
    const { GLTFLoader } = await import('/assets/vendor/three/examples/jsm/loaders/GLTFLoader.js');
    const out = [];
    for (const job of jobs) {
      const gltf = await new GLTFLoader().loadAsync(job.url);
      const root = gltf.scene;
      const skinned = [];
      root.traverse((o) => { if (o.isSkinnedMesh) skinned.push(o); });
      if (!skinned.length) throw new Error(`${job.url}: no skinned mesh`);
      const positions = () => {
        root.updateMatrixWorld(true);
        const v = new THREE.Vector3();
        const list = [];
        for (const m of skinned) {
          for (let i = 0; i < m.geometry.attributes.position.count; i++) {
            m.getVertexPosition(i, v);
            list.push(v.applyMatrix4(m.matrixWorld).toArray());
          }
        }
        return list;
      };
      const rest = positions();
      if (job.time != null) {
        const clip = gltf.animations.find((a) => a.name === 'rigserve_preview');
        if (!clip) throw new Error(`${job.url}: no rigserve_preview clip`);
        const mixer = new THREE.AnimationMixer(root);
        mixer.clipAction(clip).play();
        mixer.setTime(job.time);
      } else {
        const bone = skinned[0].skeleton.bones[job.bone];
        bone.quaternion.premultiply(new THREE.Quaternion().fromArray(job.rotation));
      }
      out.push({
        joints: skinned[0].skeleton.bones.length,
        skinned_meshes: skinned.length,
        clips: gltf.animations.map((a) => a.name),
        rest,
        posed: positions(),
      });
    }
    return out;
  }, jobs);
} finally {
  await browser.close();
}
if (errors.length) console.error(errors.join('\n'));
writeFileSync(outPath, JSON.stringify(results));
