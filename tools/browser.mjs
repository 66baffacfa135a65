// Headless Chromium for the browser tests (tools/viewer_e2e.mjs, tools/three_deform.mjs):
// Debian's `chromium` driven by playwright-core, WebGL through SwiftShader so that it
// renders on machines without a GPU.
import { chromium } from 'playwright-core';

export const CHROMIUM = process.env.RIGSERVE_CHROMIUM || '/usr/bin/chromium';

export async function launch() {
  return chromium.launch({
    executablePath: CHROMIUM,
    headless: true,
    args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
  });
}

// Collects what would otherwise scroll by unseen: uncaught errors and console errors.
export function watchErrors(page) {
  const errors = [];
  page.on('pageerror', (e) => errors.push(`pageerror: ${e.message}`));
  page.on('console', (m) => { if (m.type() === 'error') errors.push(`console: ${m.text()}`); });
  return errors;
}
