// The viewer's memory as a user switches volumes: the server's resident memory (VmRSS) idle, after
// the final frame of each volume opened in turn (a study, the cranium, the study, the cranium, the
// study), and once the page is closed and the release delay has passed (every volume released).
//
// usage: node bench/viewer_memory.mjs build/hybrid-octree STUDY.nhdr [--surface 400] [--release-s 12]
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { launch, loadPuppeteer, startServer } from '../tests/e2e/lib.mjs';

const puppeteer = await loadPuppeteer();
const exe = process.argv[2] || 'build/hybrid-octree';
const study = process.argv[3];
const arg = (name, dflt) => { const i = process.argv.indexOf(name); return i > 0 ? Number(process.argv[i + 1]) : dflt; };
const surface = arg('--surface', 0), releaseS = arg('--release-s', 12);
if (!study) {
  console.error('usage: node bench/viewer_memory.mjs build/hybrid-octree STUDY.nhdr [--surface ISO] [--release-s S]');
  process.exit(2);
}

// A data directory holding the study (its header and raw file) and the cranium, linked where the
// file system allows (a copy otherwise).
const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'hyb-memory-'));
const place = (file) => {
  const to = path.join(dir, path.basename(file));
  try { fs.linkSync(file, to); } catch { fs.copyFileSync(file, to); }
};
place(study);
const raw = fs.readFileSync(study, 'utf8').match(/^data file: (.+)$/m);
if (raw) place(path.join(path.dirname(study), raw[1].trim()));
place('/usr/share/doc/invesalius-examples/examples/Cranium.inv3');

const { server, url } = startServer(exe, ['--data-dir', dir]);
const rssMb = () => Number(fs.readFileSync(`/proc/${server.pid}/status`, 'utf8').match(/VmRSS:\s+(\d+)/)[1]) / 1024;
const rows = [];
let browser;
try {
  const pageUrl = await url;
  await new Promise((r) => setTimeout(r, 1000));
  rows.push(['idle', rssMb()]);
  browser = await launch(puppeteer);
  const page = await browser.newPage();
  await page.setViewport({ width: 900, height: 720 });
  await page.goto(pageUrl);
  await page.waitForFunction(() => document.querySelectorAll('#volumes option').length >= 3, { timeout: 60000 });
  if (surface) await page.evaluate((v) => { document.getElementById('iso').value = v; document.getElementById('iso-number').value = v; }, surface);
  const names = [path.basename(study), 'Cranium.inv3', path.basename(study), 'Cranium.inv3', path.basename(study)];
  for (let k = 0; k < names.length; ++k) {
    const t0 = performance.now();
    const value = await page.evaluate((n) => [...document.querySelectorAll('#volumes option')].find((o) => o.textContent === n).value, names[k]);
    await page.select('#volumes', value);
    await page.waitForFunction((n, c) => window.hybViewer.opened().filter((o) => o.scene === n).length >= c, { timeout: 600000 }, names[k],
      names.slice(0, k + 1).filter((x) => x === names[k]).length);
    if (surface && k === 0) await page.click('#surface-on');
    await page.waitForFunction((n, v) => window.hybViewer.metrics().some((m) => m.scene === n && m.quality === 'final' && (!v || m.iso === v)),
      { timeout: 600000 }, names[k], surface);
    await page.evaluate(() => { window.hybViewer.state.metrics.length = 0; });
    rows.push([`${names[k]} shown (${((performance.now() - t0) / 1000).toFixed(1)} s to its final frame)`, rssMb()]);
  }
  await browser.close();
  browser = null;
  await new Promise((r) => setTimeout(r, releaseS * 1000));
  rows.push([`page closed, ${releaseS} s later`, rssMb()]);
} finally {
  if (browser) await browser.close();
  server.kill('SIGTERM');
  fs.rmSync(dir, { recursive: true, force: true });
}
for (const [what, mb] of rows) console.log(`${what.padEnd(56)} ${mb.toFixed(0).padStart(6)} MB`);
