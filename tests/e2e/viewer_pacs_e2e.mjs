// End-to-end test of `hybrid-octree view --pacs` against a real archive (Debian's Orthanc with its
// DICOMweb plugin, started here on a free port with HTTP basic authentication, stopped at the end):
// the page searches the PACS, lists the series found, opens one with its load's progress shown
// (a preview of a few instances drawn first, then the retrieval and the build) and draws it in the
// preview's place; a server started again opens the same series from
// its scene cache without retrieving it; once the archive holds one more instance of the series,
// the cache is not served and the series is retrieved and built again. A search the archive
// refuses is one message on the page.
//
// usage: node tests/e2e/viewer_pacs_e2e.mjs BUILD/hybrid-octree [--screenshot page.png]
import { spawn } from 'node:child_process';
import fs from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';
import { checklist, dicomElement, dicomFile, launch, loadPuppeteer, startServer, watchConsole } from './lib.mjs';

const puppeteer = await loadPuppeteer();
const exe = process.argv[2] || 'build/hybrid-octree';
const shotAt = process.argv.indexOf('--screenshot');
const screenshot = shotAt > 0 ? process.argv[shotAt + 1] : null;
const { check, failures } = checklist();

const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'hyb-pacs-'));
const user = 'hyb', password = 'e2e-secret';
const freePort = () => new Promise((resolve) => {
  const s = net.createServer().listen(0, '127.0.0.1', () => { const { port } = s.address(); s.close(() => resolve(port)); });
});

// The archive: Orthanc on 127.0.0.1, DICOM networking off, HTTP basic authentication on.
async function startOrthanc() {
  const exeOrthanc = ['/usr/sbin/Orthanc', '/usr/bin/Orthanc'].find((p) => fs.existsSync(p));
  const plugin = '/usr/share/orthanc/plugins/libOrthancDicomWeb.so';
  if (!exeOrthanc || !fs.existsSync(plugin)) throw new Error('Orthanc or its DICOMweb plugin is missing (scripts/setup.sh installs orthanc and orthanc-dicomweb)');
  const port = await freePort(), storage = path.join(dir, 'orthanc');
  fs.mkdirSync(storage);
  const config = path.join(dir, 'orthanc.json');
  fs.writeFileSync(config, JSON.stringify({
    Name: 'hyb-e2e', HttpPort: port, DicomServerEnabled: false, StorageDirectory: storage, IndexDirectory: storage, RemoteAccessAllowed: false,
    AuthenticationEnabled: true, RegisteredUsers: { [user]: password }, HttpCompressionEnabled: false, SaveJobs: false, Plugins: [plugin],
    DicomWeb: { Enable: true, Root: '/dicom-web/' },
  }));
  const log = fs.openSync(path.join(dir, 'orthanc.log'), 'w');
  const process_ = spawn(exeOrthanc, [config], { stdio: ['ignore', log, log] });
  const base = `http://127.0.0.1:${port}`, auth = { Authorization: 'Basic ' + Buffer.from(`${user}:${password}`).toString('base64') };
  for (let k = 0; k < 300; ++k) {
    try {
      if ((await fetch(`${base}/system`, { headers: auth })).ok) return { process: process_, base, auth };
    } catch { /* not listening yet */ }
    await new Promise((r) => setTimeout(r, 100));
  }
  process_.kill('SIGKILL');
  throw new Error(`Orthanc did not start (see ${path.join(dir, 'orthanc.log')})`);
}

// Slice k of an axial CT series of 48×48 images, 1 mm pixels, 2 mm apart: -1000 HU outside a
// ball of bone (1000 HU, radius 18 mm) centred in the volume.
const study = '1.2.826.0.1.3680043.8.498.7700', series = `${study}.1`;
function ctSlice(k) {
  const n = 48, instance = `${series}.${k + 1}`, z = 2 * k;
  const us = (v) => Buffer.from([v & 255, v >> 8]);
  const pixels = Buffer.alloc(2 * n * n);
  for (let y = 0; y < n; ++y)
    for (let x = 0; x < n; ++x) pixels.writeInt16LE(Math.hypot(x - 23.5, y - 23.5, z - 23) < 18 ? 1000 : -1000, 2 * (y * n + x));
  const data = Buffer.concat([
    dicomElement(8, 0x16, 'UI', '1.2.840.10008.5.1.4.1.1.2'), dicomElement(8, 0x18, 'UI', instance), dicomElement(8, 0x20, 'DA', '20240102'),
    dicomElement(8, 0x60, 'CS', 'CT'), dicomElement(8, 0x103e, 'LO', 'HEAD 2.0'), dicomElement(0x10, 0x10, 'PN', 'E2E^PACS'),
    dicomElement(0x10, 0x20, 'LO', 'HYB-E2E'), dicomElement(0x18, 0x50, 'DS', '2'), dicomElement(0x20, 0x0d, 'UI', study),
    dicomElement(0x20, 0x0e, 'UI', series), dicomElement(0x20, 0x11, 'IS', '2'), dicomElement(0x20, 0x13, 'IS', String(k + 1)),
    dicomElement(0x20, 0x32, 'DS', `-24\\-24\\${z}`), dicomElement(0x20, 0x37, 'DS', '1\\0\\0\\0\\1\\0'), dicomElement(0x28, 0x02, 'US', us(1)),
    dicomElement(0x28, 0x04, 'CS', 'MONOCHROME2'), dicomElement(0x28, 0x10, 'US', us(n)), dicomElement(0x28, 0x11, 'US', us(n)),
    dicomElement(0x28, 0x30, 'DS', '1\\1'), dicomElement(0x28, 0x100, 'US', us(16)), dicomElement(0x28, 0x101, 'US', us(16)),
    dicomElement(0x28, 0x102, 'US', us(15)), dicomElement(0x28, 0x103, 'US', us(1)), dicomElement(0x28, 0x1052, 'DS', '0'),
    dicomElement(0x28, 0x1053, 'DS', '1'), dicomElement(0x7fe0, 0x10, 'OW', pixels)]);
  return dicomFile(instance, data);
}

async function upload(orthanc, k) {
  const r = await fetch(`${orthanc.base}/instances`, { method: 'POST', headers: orthanc.auth, body: ctSlice(k) });
  if (!r.ok) throw new Error(`Orthanc refused slice ${k} (HTTP ${r.status})`);
}

let orthanc, browser;
const servers = [];
try {
  orthanc = await startOrthanc();
  for (let k = 0; k < 24; ++k) await upload(orthanc, k);
  const root = `${orthanc.base}/dicom-web`, address = `${root}/studies/${study}/series/${series}`, cache = path.join(dir, 'cache');
  process.env.HYB_DICOMWEB_USER = `${user}:${password}`;
  browser = await launch(puppeteer);

  // A server with the PACS and a page on it; resolves with the page once the PACS panel shows.
  const serve = async () => {
    const started = startServer(exe, ['--pacs', root, '--pacs-cache', cache, '--pacs-preview', '4']);
    servers.push(started.server);
    const page = await browser.newPage();
    await page.setViewport({ width: 1100, height: 720 });
    const errors = watchConsole(page);
    await page.goto(await started.url);
    await page.waitForFunction(() => !document.getElementById('pacs').hidden, { timeout: 60000 });
    return { page, errors, server: started.server };
  };
  // Searches for the test's patient, opens the one series found and waits for its final frame;
  // resolves with the load's tasks, the first frame's time from the click and the dims.
  const openFromPacs = async (page) => {
    await page.$eval('#pacs-patient', (e) => { e.value = 'E2E*'; });
    await page.click('#pacs-search button');
    await page.waitForFunction(() => document.querySelectorAll('#pacs-results button').length > 0, { timeout: 60000 });
    const listed = await page.$$eval('#pacs-results button', (b) => b.map((x) => ({ label: x.textContent, url: x.title })));
    const clicked = await page.evaluate(() => performance.now());
    await page.click('#pacs-results button');
    await page.waitForFunction((s) => window.hybViewer.metrics().some((m) => m.scene === s && m.quality === 'final' && !m.preview), { timeout: 180000 }, address);
    return page.evaluate((s, t0, l) => {
      const frames = window.hybViewer.metrics().filter((m) => m.scene === s);
      return { listed: l, tasks: [...new Set(window.hybViewer.loads().filter((x) => x.scene === s).map((x) => x.task))],
        firstFrameMs: frames[0].paintedAt - t0, name: document.getElementById('volume-name').textContent,
        // what was shown, in order: the preview's frames, then the scene's (never a preview's after the scene's)
        shown: window.hybViewer.opened().filter((o) => o.scene === s).map((o) => (o.preview ? 'preview' : 'scene')),
        previewAfterScene: frames.some((m, i) => m.preview && frames.slice(0, i).some((x) => !x.preview)) };
    }, address, clicked, listed);
  };

  // 1. Searched, listed, opened: the retrieval's and the build's progress shown, the series drawn.
  let s = await serve();
  const first = await openFromPacs(s.page);
  check(first.listed.length === 1 && first.listed[0].label === 'E2E^PACS · 20240102 · CT · HEAD 2.0 · 24 instances' && first.listed[0].url === address,
    `the search lists the series with its label and address (${first.listed.map((l) => l.label).join(' | ')})`);
  check(first.tasks.some((t) => t.startsWith('DICOMweb')) && first.tasks.length >= 2, `the load's progress names the retrieval and the build (${first.tasks.join(', ')})`);
  check(first.name.includes('48×48×24') && !first.name.includes('preview'), `the series is shown (${first.name})`);
  check(first.shown.join(',') === 'preview,scene' && !first.previewAfterScene && first.tasks.includes('DICOMweb preview'),
    `a preview of 4 instances is shown first, then the series in its place (${first.shown.join(', ')})`);
  console.log(`     first frame ${first.firstFrameMs.toFixed(0)} ms after the click (retrieved and built)`);
  const cached = fs.readdirSync(cache);
  check(cached.includes(`${series}.hoct`) && cached.includes(`${series}.instances`), `the scene is cached (${cached.join(', ')})`);
  const fits = await s.page.evaluate(() => { const p = document.getElementById('panel'); return p.scrollWidth <= p.clientWidth; });
  check(fits, 'the PACS panel fits its column in a 1100-pixel window');
  if (screenshot) await s.page.screenshot({ path: screenshot });
  check(s.errors.length === 0, `the console shows no errors${s.errors.length ? ': ' + s.errors.join(' | ') : ''}`);

  // A search the archive refuses: one message, on the page.
  await s.page.$eval('#pacs-date', (e) => { e.value = 'yesterday'; });
  await s.page.click('#pacs-search button');
  await s.page.waitForFunction(() => !document.getElementById('message').hidden, { timeout: 60000 });
  const refused = await s.page.$eval('#message', (e) => e.textContent);
  check(refused.includes('pacs: ') && refused.includes("'yesterday' invalid") && !refused.includes(password), `a bad date is refused in one line (${refused})`);
  s.server.kill('SIGTERM');

  // 2. Another server, the same cache: the series opens without being retrieved again.
  s = await serve();
  const again = await openFromPacs(s.page);
  check(!again.tasks.some((t) => t.startsWith('DICOMweb')), `opened again, the series comes from the cache (${again.tasks.join(', ') || 'no load tasks'})`);
  check(again.shown.join(',') === 'scene', `from the cache, no preview is made (${again.shown.join(', ')})`);
  console.log(`     first frame ${again.firstFrameMs.toFixed(0)} ms after the click (from the cache)`);
  s.server.kill('SIGTERM');

  // 3. The archive holds one more instance of the series: the cache is not served.
  await upload(orthanc, 24);
  s = await serve();
  const changed = await openFromPacs(s.page);
  check(changed.tasks.some((t) => t.startsWith('DICOMweb')), `with its instances changed, the series is retrieved again (${changed.tasks.join(', ')})`);
  check(changed.name.includes('48×48×25'), `and shows the new instance (${changed.name})`);
  check(changed.listed[0].label.endsWith('25 instances'), `the listing counts it (${changed.listed[0].label})`);
} catch (e) {
  check(false, e.message);
} finally {
  if (browser) await browser.close();
  for (const server of servers) server.kill('SIGTERM');
  if (orthanc) orthanc.process.kill('SIGTERM');
  await new Promise((r) => setTimeout(r, 500));
  fs.rmSync(dir, { recursive: true, force: true });
}
console.log(failures() ? `viewer_pacs_e2e: ${failures()} failed` : 'viewer_pacs_e2e: all passed');
process.exit(failures() ? 1 : 0);
