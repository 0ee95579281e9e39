// End-to-end test of switching volumes in `hybrid-octree view --data-dir` (headless chromium): a
// volume whose file carries no orientation says so; the load's progress is shown; with one
// volume's surface ready, opening another says nothing of that surface, and going back while the
// other's surface builds leaves no stale label and paints no frame of the volume left.
//
// usage: node tests/e2e/viewer_switch_e2e.mjs BUILD/hybrid-octree [--screenshot page.png]
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { checklist, launch, loadPuppeteer, startServer, watchConsole } from './lib.mjs';

const puppeteer = await loadPuppeteer();
const exe = process.argv[2] || 'build/hybrid-octree';
const shotAt = process.argv.indexOf('--screenshot');
const screenshot = shotAt > 0 ? process.argv[shotAt + 1] : null;
const { check, failures } = checklist();

// The data directory: the cranium, and a CT-like blob (-1000 outside, +1000 in a ball, a bump on
// one side) as a NRRD without orientation.
const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'hyb-switch-'));
fs.copyFileSync('/usr/share/doc/invesalius-examples/examples/Cranium.inv3', path.join(dir, 'Cranium.inv3'));
const n = 96;
const samples = new Int16Array(n * n * n);
for (let z = 0, i = 0; z < n; ++z)
  for (let y = 0; y < n; ++y)
    for (let x = 0; x < n; ++x, ++i) {
      const r = Math.hypot(x - 47.5, y - 47.5, z - 47.5), bump = Math.hypot(x - 78, y - 47.5, z - 47.5);
      samples[i] = Math.round(-1000 + 2000 * Math.min(1, Math.max(0, 30 - r, 8 - bump)));
    }
const header = `NRRD0004\ntype: short\ndimension: 3\nsizes: ${n} ${n} ${n}\nendian: little\nencoding: raw\n\n`;
fs.writeFileSync(path.join(dir, 'blob.nrrd'), Buffer.concat([Buffer.from(header), Buffer.from(samples.buffer)]));

const started = startServer(exe, ['--data-dir', dir]);
const server = started.server;
let browser;
try {
  const url = await started.url;
  browser = await launch(puppeteer);
  const page = await browser.newPage();
  await page.setViewport({ width: 900, height: 720 });
  const consoleErrors = watchConsole(page);
  await page.goto(url);
  await page.waitForFunction(() => document.querySelectorAll('#volumes option').length >= 3, { timeout: 60000 });
  const open = async (name) => {
    const value = await page.evaluate((n) => [...document.querySelectorAll('#volumes option')].find((o) => o.textContent === n).value, name);
    await page.select('#volumes', value);
  };
  const lastOpened = () => page.evaluate(() => { const o = window.hybViewer.opened(); return o.length ? o[o.length - 1].scene : null; });
  const waitOpened = (name, count) => page.waitForFunction((s, c) => window.hybViewer.opened().filter((o) => o.scene === s).length >= c,
    { timeout: 120000 }, name, count);
  const waitFinalWith = (scene, iso) => page.waitForFunction((s, v) => window.hybViewer.metrics().some((m) => m.scene === s && m.quality === 'final' && m.iso === v),
    { timeout: 120000 }, scene, iso);

  // The blob: no orientation in its file, and the page says so; its load's progress was shown.
  await open('blob.nrrd');
  await waitOpened('blob.nrrd', 1);
  const name = await page.evaluate(() => document.getElementById('volume-name').textContent);
  check(name.includes('orientation unknown: grid axes taken as LPS'), `a volume without orientation says so (${name})`);
  const dims = await page.evaluate(() => [...document.querySelectorAll('#volume-name .nowrap')].map((s) => s.textContent));
  check(dims.includes('96×96×96'), `the dimensions are one unbreakable piece (${dims.join(' | ')})`);
  const blobLoads = await page.evaluate(() => window.hybViewer.loads().filter((l) => l.scene === 'blob.nrrd'));
  check(blobLoads.length >= 1, `the load's progress is shown (${blobLoads.map((l) => `${l.task} ${Math.round(100 * l.progress)} %`).join(', ')})`);

  // Its 400 HU surface, drawn and ready.
  await page.click('#surface-on');
  await waitFinalWith('blob.nrrd', 400);
  await page.waitForFunction(() => window.hybViewer.surfaceLabel() === '400 ready', { timeout: 60000 });
  check(true, "the blob's 400 surface is ready");

  // The cranium: nothing of the blob's surface shows under its name; its load's progress does.
  await open('Cranium.inv3');
  await waitOpened('Cranium.inv3', 1);
  const labelAtOpen = await page.evaluate(() => window.hybViewer.opened().find((o) => o.scene === 'Cranium.inv3').surfaceLabel);
  check(labelAtOpen !== '400 ready', `the cranium's surface label does not say another volume's surface is ready ('${labelAtOpen}')`);
  const craniumLoads = await page.evaluate(() => window.hybViewer.loads().filter((l) => l.scene === 'Cranium.inv3'));
  check(craniumLoads.length >= 2, `the cranium's load reports its progress (${craniumLoads.length} messages, the last '${craniumLoads.length ? craniumLoads[craniumLoads.length - 1].task : ''}')`);
  await page.waitForFunction(() => window.hybViewer.surfaceLabel().startsWith('building 400'), { timeout: 60000 });
  check(true, "the cranium's surface is building");

  // Back to the blob while the cranium's surface builds.
  await open('blob.nrrd');
  await waitOpened('blob.nrrd', 2);
  const back = await page.evaluate(() => window.hybViewer.opened().filter((o) => o.scene === 'blob.nrrd')[1].at);
  const labelBack = await page.evaluate(() => window.hybViewer.opened().filter((o) => o.scene === 'blob.nrrd')[1].surfaceLabel);
  check(labelBack === '400 ready', `back on the blob, its surface is said ready at once ('${labelBack}')`);
  await waitFinalWith('blob.nrrd', 400);
  await new Promise((r) => setTimeout(r, 3000));  // the cranium's build would have gone on meanwhile
  const label = await page.evaluate(() => window.hybViewer.surfaceLabel());
  check(label === '400 ready', `the label stays the blob's ('${label}')`);
  const stale = await page.evaluate((t) => window.hybViewer.metrics().filter((m) => m.paintedAt > t && m.scene !== 'blob.nrrd').length, back);
  check(stale === 0, `no frame of the cranium is painted after the blob is shown again (${stale})`);
  check((await lastOpened()) === 'blob.nrrd', 'the blob is the volume shown');
  if (screenshot) await page.screenshot({ path: screenshot });
  check(consoleErrors.length === 0, `the console shows no errors${consoleErrors.length ? ': ' + consoleErrors.join(' | ') : ''}`);
} catch (e) {
  check(false, e.message);
} finally {
  if (browser) await browser.close();
  server.kill('SIGTERM');
  fs.rmSync(dir, { recursive: true, force: true });
}
console.log(failures() ? `viewer_switch_e2e: ${failures()} failed` : 'viewer_switch_e2e: all passed');
process.exit(failures() ? 1 : 0);
