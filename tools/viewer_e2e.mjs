#!/usr/bin/env node
// Drives the viewer page like a person would: pick a mesh, set options, submit, wait for
// the job, look at the result, show a bone's weights, play the motion, take screenshots.
// Prints one JSON report on stdout; tests/viewer/page.rs decides what is right.
//
// Usage: node tools/viewer_e2e.mjs BASE_URL MESH OUT_DIR [OPTIONS_JSON]
//   OPTIONS_JSON: {"category": "humanoid", "template": "auto", "animation": true, ...}
import { mkdirSync } from 'node:fs';
import { join } from 'node:path';
import { launch, watchErrors } from './browser.mjs';

const [base, mesh, outDir, optionsJson] = process.argv.slice(2);
if (!base || !mesh || !outDir) {
  console.error('usage: node tools/viewer_e2e.mjs BASE_URL MESH OUT_DIR [OPTIONS_JSON]');
  process.exit(2);
}
const options = JSON.parse(optionsJson || '{}');
mkdirSync(outDir, { recursive: true });

const browser = await launch();
const report = { errors: [] };
try {
  const page = await browser.newPage({ viewport: { width: 1100, height: 720 } });
  report.errors = watchErrors(page);
  await page.goto(`${base}/`);
  await page.waitForFunction(() => window.rigserveViewer && window.rigserveViewer.frames > 0);

  await page.setInputFiles('#file', mesh);
  for (const key of ['category', 'template']) {
    if (options[key] != null) await page.selectOption(`select[name=${key}]`, options[key]);
  }
  for (const key of ['seed', 'samples', 'max_bones']) {
    if (options[key] != null) await page.fill(`input[name=${key}]`, String(options[key]));
  }
  if (options.animation != null) await page.setChecked('input[name=animation]', options.animation);
  await page.click('#submit');

  // The progress bar and stage list as they go, sampled while waiting.
  report.progress = [];
  const deadline = Date.now() + (options.timeout_ms || 180000);
  for (;;) {
    const s = await page.evaluate(() => ({
      state: window.rigserveViewer.state,
      bar: document.querySelector('#progress').value,
    }));
    report.progress.push(s);
    if (s.state === 'ready' || s.state === 'failed' || Date.now() > deadline) break;
    await page.waitForTimeout(100);
  }
  const viewer = () => page.evaluate(() => JSON.parse(JSON.stringify(window.rigserveViewer)));
  report.loaded = await viewer();
  if (report.loaded.state !== 'ready') throw new Error(`the page ended in ${report.loaded.state}: ${report.loaded.error}`);

  report.stagesShown = await page.$$eval('#stages li.done', (lis) => lis.map((l) => l.textContent));
  report.downloads = {};
  for (const id of ['download-glb', 'download-skeleton']) {
    const href = await page.getAttribute(`#${id}`, 'href');
    const status = await page.evaluate(async (u) => (await fetch(u)).status, href);
    report.downloads[id] = { href, status };
  }

  // Pixels of the overlay's colour prove the skeleton is on the canvas, not just counted.
  const overlayPixels = () => page.evaluate(() => {
    const src = document.querySelector('#canvas');
    const c = document.createElement('canvas');
    c.width = src.width;
    c.height = src.height;
    const ctx = c.getContext('2d');
    ctx.drawImage(src, 0, 0);
    const d = ctx.getImageData(0, 0, c.width, c.height).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
      if (d[i] < 100 && d[i + 1] > 150 && d[i + 2] > 200) n += 1; // the cyan bone lines
    }
    return n;
  });
  // A loaded machine may not have drawn the first frame yet: give it up to 5 s.
  let px = 0;
  for (let i = 0; i < 50; i++) {
    px = await overlayPixels();
    if (px > 50) break;
    await page.waitForTimeout(100);
  }
  report.overlayPixels = px;
  await page.screenshot({ path: join(outDir, 'rest.png') });

  const bone = Math.min(1, report.loaded.joints - 1);
  await page.selectOption('#bone', String(bone));
  report.heat = await page.evaluate(() => window.rigserveViewer.selectedBone);

  const restShot = await page.locator('#canvas').screenshot();
  await page.click('#play');
  await page.waitForTimeout(1300);
  report.playing = await viewer();
  const movingShot = await page.locator('#canvas').screenshot();
  report.canvasChangedWhilePlaying = !restShot.equals(movingShot);
  await page.screenshot({ path: join(outDir, 'viewer.png') });
  await page.click('#play');
  report.paused = await viewer();
} catch (e) {
  report.failure = String(e && e.stack || e);
} finally {
  await browser.close();
}
console.log(JSON.stringify(report));
