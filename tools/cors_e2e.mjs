// A page served from another loopback origin uses the API as a front-end would: upload
// (a preflighted POST: model/obj is not a CORS-safelisted type), follow the job over SSE,
// download the GLB and the bone tree. A second page, from an origin the server does not
// list, tries the same upload and must be blocked by the browser.
//   node tools/cors_e2e.mjs API_BASE LISTED_PORT UNLISTED_PORT MESH
// Prints one JSON report: {listed: {...}, unlisted: {...}}.
import http from 'node:http';
import fs from 'node:fs';
import { launch, watchErrors } from './browser.mjs';

const [api, listedPort, unlistedPort, meshPath] = process.argv.slice(2);
const mesh = fs.readFileSync(meshPath).toString('base64');

function serve(port) {
  const server = http.createServer((_, res) => {
    res.writeHead(200, { 'content-type': 'text/html' });
    res.end('<!doctype html><title>front-end</title>');
  });
  return new Promise((ok) => server.listen(Number(port), '127.0.0.1', () => ok(server)));
}

// Runs in the page: everything a front-end does, with the browser's CORS checks.
async function frontEnd({ api, mesh }) {
  const out = { steps: [] };
  try {
    const body = Uint8Array.from(atob(mesh), (c) => c.charCodeAt(0));
    const r = await fetch(`${api}/v1/jobs?seed=1`, {
      method: 'POST', body, headers: { 'content-type': 'model/obj' },
    });
    out.status = r.status;
    out.location = r.headers.get('location');
    const job = await r.json();
    out.steps.push('uploaded');
    out.final = await new Promise((done, fail) => {
      const es = new EventSource(`${api}/v1/jobs/${job.id}/events`);
      const timer = setTimeout(() => { es.close(); fail(new Error('no terminal event in 120 s')); }, 120000);
      es.addEventListener('job', (e) => {
        const ev = JSON.parse(e.data);
        if (['succeeded', 'failed', 'canceled', 'expired'].includes(ev.status)) {
          clearTimeout(timer); es.close(); done(ev.status);
        }
      });
      es.onerror = () => { if (es.readyState === EventSource.CLOSED) { clearTimeout(timer); fail(new Error('SSE blocked')); } };
    });
    out.steps.push('followed');
    const glb = new Uint8Array(await (await fetch(`${api}/v1/jobs/${job.id}/result.glb`)).arrayBuffer());
    out.glbMagic = String.fromCharCode(...glb.slice(0, 4));
    out.glbBytes = glb.length;
    const tree = await (await fetch(`${api}/v1/jobs/${job.id}/skeleton.json`)).json();
    out.bones = tree.bones.length;
    out.steps.push('downloaded');
  } catch (e) {
    out.error = String(e);
  }
  return out;
}

const servers = [await serve(listedPort), await serve(unlistedPort)];
const browser = await launch();
const report = {};
try {
  for (const [name, port] of [['listed', listedPort], ['unlisted', unlistedPort]]) {
    const page = await browser.newPage();
    const errors = watchErrors(page);
    await page.goto(`http://127.0.0.1:${port}/`);
    report[name] = await page.evaluate(frontEnd, { api, mesh });
    report[name].pageErrors = errors;
    await page.close();
  }
} finally {
  await browser.close();
  servers.forEach((s) => s.close());
}
console.log(JSON.stringify(report));
