// End-to-end test of switching volumes in `hybrid-octree view --data-dir` (headless chromium): a
// volume whose file carries no orientation says so; the load's progress is shown; with one
// volume's surface ready, opening another says nothing of that surface, and going back while the
// other's surface builds leaves no stale label and paints no frame of the volume left. A DICOM
// series that cannot be read: the volume shown stays, on screen and in the menu, and the page says
// why in the menu's words (not the series' UID) until the message is dismissed. The menu fits its
// panel in a window 1100 pixels wide. On the cranium, the data directory's mesh and a primitive are
// drawn, as polygons and scan-converted, and the render command carries them.
//
// usage: node tests/e2e/viewer_switch_e2e.mjs BUILD/hybrid-octree [--screenshot page.png]
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { checklist, dicomElement, dicomFile, launch, loadPuppeteer, startServer, watchConsole } from './lib.mjs';

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

// A DICOM series of two 4×4 CT images without Image Orientation (Patient): listed (its headers
// scan as images), but the reader cannot order its slices.
const brokenUid = '1.2.826.0.1.3680043.8.498.4242', description = 'Head CT 0.625 mm, bone kernel H70h, arterial phase, contrast';
fs.mkdirSync(path.join(dir, 'broken-ct'));
for (let k = 0; k < 2; ++k) {
  const instance = `${brokenUid}.${k + 1}`, us = (n) => Buffer.from([n & 255, n >> 8]);
  const data = Buffer.concat([dicomElement(8, 0x16, 'UI', '1.2.840.10008.5.1.4.1.1.2'), dicomElement(8, 0x18, 'UI', instance), dicomElement(8, 0x60, 'CS', 'CT'),
    dicomElement(8, 0x103e, 'LO', description), dicomElement(0x20, 0x0e, 'UI', brokenUid), dicomElement(0x20, 0x11, 'IS', '7'),
    dicomElement(0x20, 0x32, 'DS', `0\\0\\${2 * k}`), dicomElement(0x28, 0x10, 'US', us(4)), dicomElement(0x28, 0x11, 'US', us(4)),
    dicomElement(0x7fe0, 0x10, 'OW', Buffer.alloc(32))]);
  fs.writeFileSync(path.join(dir, 'broken-ct', `slice${k}.dcm`), dicomFile(instance, data));
}

// A mesh of the user's in the data directory: an implant-like ball (an icosphere of radius 20 mm,
// ASCII STL, patient mm) inside the cranium.
function icosphereStl(center, radius, levels) {
  const t = (1 + Math.sqrt(5)) / 2;
  let v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]];
  let f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2],
    [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]];
  const unit = (p) => { const l = Math.hypot(...p); return p.map((c) => c / l); };
  v = v.map(unit);
  for (let k = 0; k < levels; ++k) {
    const mid = new Map(), next = [];
    const m = (a, b) => { const key = a < b ? `${a},${b}` : `${b},${a}`; if (!mid.has(key)) { v.push(unit(v[a].map((c, i) => c + v[b][i]))); mid.set(key, v.length - 1); } return mid.get(key); };
    for (const [a, b, c] of f) { const ab = m(a, b), bc = m(b, c), ca = m(c, a); next.push([a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]); }
    f = next;
  }
  const p = (i) => v[i].map((c, k) => (center[k] + radius * c).toFixed(4)).join(' ');
  return `solid implant\n${f.map(([a, b, c]) => `facet normal 0 0 0\nouter loop\nvertex ${p(a)}\nvertex ${p(b)}\nvertex ${p(c)}\nendloop\nendfacet\n`).join('')}endsolid implant\n`;
}
fs.mkdirSync(path.join(dir, 'models'));
fs.writeFileSync(path.join(dir, 'models', 'implant.stl'), icosphereStl([122, -122, 80], 20, 3));

const started = startServer(exe, ['--data-dir', dir]);
const server = started.server;
let browser;
try {
  const url = await started.url;
  browser = await launch(puppeteer);
  const page = await browser.newPage();
  await page.setViewport({ width: 1100, height: 720 });
  const consoleErrors = watchConsole(page);
  // Decoding as slow as on a busy machine when asked (window.slowDecodeMs): messages that come
  // after a frame are handled before it is painted.
  await page.evaluateOnNewDocument(() => {
    const decode = window.createImageBitmap.bind(window);
    window.createImageBitmap = async (...args) => {
      const bitmap = await decode(...args);
      if (window.slowDecodeMs) await new Promise((r) => setTimeout(r, window.slowDecodeMs));
      return bitmap;
    };
  });
  await page.goto(url);
  await page.waitForFunction(() => document.querySelectorAll('#volumes option').length >= 4, { timeout: 60000 });
  // Opens the volume whose menu label is @p name (or starts with it, with @p prefix).
  const open = async (name, prefix = false) => {
    const value = await page.evaluate((n, p) => [...document.querySelectorAll('#volumes option')].find((o) => (p ? o.textContent.startsWith(n) : o.textContent === n)).value,
      name, prefix);
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

  // Its 400 HU surface, drawn and ready: its simplified levels' 'ready' comes while the final
  // frame before it is decoded, and the frame's header must not say it is still being simplified.
  await page.evaluate(() => { window.slowDecodeMs = 400; });
  await page.click('#surface-on');
  await waitFinalWith('blob.nrrd', 400);
  await page.waitForFunction(() => window.hybViewer.surfaceLabel() === '400 ready', { timeout: 60000 });
  check(true, "the blob's 400 surface is ready");
  await page.evaluate(() => { window.slowDecodeMs = 0; });

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

  // The broken series: its open fails, the blob stays shown and the page says why until dismissed.
  const menuFits = () => page.evaluate(() => {
    const menu = document.getElementById('volumes').getBoundingClientRect(), panel = document.getElementById('panel');
    const box = panel.getBoundingClientRect();
    return { fits: menu.right <= box.right - 12 && panel.scrollWidth <= panel.clientWidth, menu: Math.round(menu.right), panel: Math.round(box.right) };
  });
  const fitsBefore = await menuFits();
  const brokenLabel = await page.evaluate(() => [...document.querySelectorAll('#volumes option')].find((o) => o.textContent.startsWith('broken-ct/')).textContent);
  await open('broken-ct/', true);
  await page.waitForFunction(() => document.querySelector('#message .sticky'), { timeout: 60000 });
  const failed = () => page.evaluate(() => {
    const $ = (id) => document.getElementById(id), sticky = document.querySelector('#message .sticky');
    return { message: sticky ? sticky.firstChild.textContent : null, shown: !$('message').hidden, menu: $('volumes').selectedOptions[0].textContent,
      overlay: $('overlay').textContent, loading: !$('loading').hidden, name: $('volume-name').textContent };
  });
  const f = await failed();
  check(f.message.includes(`cannot open ${brokenLabel}: `) && f.message.includes(': broken-ct/slice') && f.message.includes('Image Orientation (Patient) missing') && !f.message.includes(dir),
    `the failed open says why, in the menu's words (${f.message})`);
  check(!f.message.includes(brokenUid) && !f.overlay.includes(brokenUid), "the series' UID shows nowhere");
  check(f.menu === 'blob.nrrd', `the menu names the volume shown (${f.menu})`);
  check(!f.loading && !f.overlay.includes('broken-ct'), `the overlay says nothing of the failed volume (${f.overlay})`);
  check(f.name.startsWith('blob.nrrd'), `the volume's name is the blob's (${f.name})`);
  check((await page.evaluate(() => window.hybViewer.state.displayed.scene)) === 'blob.nrrd', "the frame on screen is the blob's");
  const fitsAfter = await menuFits();
  check(fitsBefore.fits && fitsAfter.fits, `the menu fits its panel in a 1100-pixel window (its right edge ${fitsAfter.menu}, the panel's ${fitsAfter.panel})`);
  if (screenshot) await page.screenshot({ path: screenshot });
  // The page still asks for and paints the blob's frames.
  const asked = await page.evaluate(() => { window.hybViewer.request(false); return performance.now(); });
  await page.waitForFunction((t) => window.hybViewer.metrics().some((m) => m.paintedAt > t && m.quality === 'final'), { timeout: 120000 }, asked);
  const after = await page.evaluate((t) => window.hybViewer.metrics().filter((m) => m.paintedAt > t).map((m) => m.scene), asked);
  check(after.every((s) => s === 'blob.nrrd'), `the frames painted after the failure are the blob's (${[...new Set(after)].join(', ')})`);
  await new Promise((r) => setTimeout(r, 7000));
  const later = await failed();
  check(later.shown && later.message === f.message, 'the reason is still shown 7 s later');
  await page.click('#message .sticky button');
  const dismissed = await failed();
  check(!dismissed.shown && dismissed.message === null, 'the dismiss button takes it away');

  // The user's geometry on the cranium: the data directory's mesh and a primitive, drawn as
  // polygons and scan-converted, each final frame another image than the one without.
  await open('Cranium.inv3');
  await waitOpened('Cranium.inv3', 2);
  const meshes = await page.$$eval('#mesh option', (o) => o.map((x) => x.value));
  check(meshes.includes('models/implant.stl') && !(await page.$eval('#mesh-row', (e) => e.hidden)), `the page lists the data directory's meshes (${meshes.join(', ')})`);
  const finalImage = async () => {
    const asked = await page.evaluate(() => { window.hybViewer.request(false); return performance.now(); });
    await page.waitForFunction((t) => window.hybViewer.metrics().some((m) => m.paintedAt > t && m.quality === 'final' && m.scene === 'Cranium.inv3'), { timeout: 120000 }, asked);
    return page.evaluate(() => document.getElementById('view').toDataURL());
  };
  const bare = await finalImage();
  await page.click('#geometry-on');
  await page.select('#mesh', 'models/implant.stl');
  await page.$eval('#primitive', (e) => { e.value = 'plane:122,-122,80,0,0,1'; });
  const polygons = await finalImage();
  await page.select('#mesh-method', 'scan-convert');
  const scanned = await finalImage();
  const shownError = await page.evaluate(() => (document.getElementById('message').hidden ? '' : document.getElementById('message').textContent));
  check(polygons !== bare && scanned !== bare && scanned !== polygons && !shownError,
    `the mesh and the plane are drawn on the cranium, as polygons and scan-converted${shownError ? ` (${shownError})` : ''}`);
  const command = await page.$eval('#command', (e) => e.value);
  check(command.includes('--mesh ') && command.includes('implant.stl') && command.includes('--mesh-method scan-convert') && command.includes('--primitive'),
    `the render command draws the same geometry (${command})`);
  if (screenshot) await page.screenshot({ path: screenshot.replace(/\.png$/, '-geometry.png') });
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
