// The viewer opening a series of a PACS (bench/dicomweb_bench.sh starts the archive and passes its
// root): the time from the click on the series to its first frame on the page (of the preview when
// the series is retrieved), to the first frame of the whole series and to its final frame, with the
// series retrieved and built (an empty scene cache), then from the scene cache (a server started
// again), in one run. Uses the e2e tests' puppeteer-core and chromium.
//   node bench/viewer_pacs_bench.mjs BUILD/hybrid-octree PACS_ROOT SERIES_URL
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { launch, loadPuppeteer, startServer } from '../tests/e2e/lib.mjs';

const [exe, root, series] = process.argv.slice(2);
const puppeteer = await loadPuppeteer();
const cache = fs.mkdtempSync(path.join(os.tmpdir(), 'hyb-pacs-bench-'));
const browser = await launch(puppeteer);
try {
  for (const run of ['retrieved and built', 'from the scene cache']) {
    const { server, url } = startServer(exe, ['--pacs', root, '--pacs-cache', cache]);
    try {
      const page = await browser.newPage();
      await page.setViewport({ width: 1100, height: 720 });
      await page.goto(await url);
      await page.waitForFunction(() => !document.getElementById('pacs').hidden, { timeout: 60000 });
      await page.click('#pacs-search button');
      await page.waitForFunction((s) => [...document.querySelectorAll('#pacs-results button')].some((b) => b.title === s), { timeout: 60000 }, series);
      const t0 = await page.evaluate((s) => {
        [...document.querySelectorAll('#pacs-results button')].find((b) => b.title === s).click();
        return performance.now();
      }, series);
      await page.waitForFunction((s) => window.hybViewer.metrics().some((m) => m.scene === s && m.quality === 'final' && !m.preview), { timeout: 600000 }, series);
      const r = await page.evaluate((s, t) => {
        const frames = window.hybViewer.metrics().filter((m) => m.scene === s);
        const scene = frames.find((m) => !m.preview);
        return { first: frames[0].paintedAt - t, quality: frames[0].quality, preview: frames[0].preview, scene: scene.paintedAt - t,
                 final: frames.find((m) => m.quality === 'final' && !m.preview).paintedAt - t };
      }, series, t0);
      const s = (ms) => `${(ms / 1000).toFixed(1)} s`;
      console.log(`${run.padEnd(22)} first frame ${s(r.first)} (${r.quality}${r.preview ? ', preview' : ''}), ` +
                  `first of the whole series ${s(r.scene)}, its final frame ${s(r.final)}`);
    } finally {
      server.kill('SIGTERM');
    }
  }
} finally {
  await browser.close();
  fs.rmSync(cache, { recursive: true, force: true });
}
