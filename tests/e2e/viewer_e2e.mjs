// End-to-end test of `hybrid-octree view` in Debian's headless chromium (puppeteer-core): the page
// loads the cranium, a drag orbits it, a preset and the isovalue change, frames arrive, the final
// frame after the motion equals `hybrid-octree render` of the command line the page shows
// (PSNR >= 40 dB), requests without the token fail, and the console stays clean.
//
// usage: node tests/e2e/viewer_e2e.mjs BUILD/hybrid-octree [--screenshot page.png]
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { checklist, launch, loadPuppeteer, startServer, watchConsole } from './lib.mjs';

const puppeteer = await loadPuppeteer();
const exe = path.resolve(process.argv[2] || 'build/hybrid-octree');
const shotAt = process.argv.indexOf('--screenshot');
const screenshot = shotAt > 0 ? process.argv[shotAt + 1] : null;
const volume = '/usr/share/doc/invesalius-examples/examples/Cranium.inv3';
const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'hyb-e2e-'));
const { check, failures } = checklist();

// The server, on a free port; its first line names the URL with the token.
const started = startServer(exe, [volume]);
const server = started.server;
const url = await started.url;
const base = url.slice(0, url.indexOf('?'));
let browser;
try {
  // Without the token: refused, for the page and for its assets.
  check((await fetch(base)).status === 403, 'the page without the token is refused (403)');
  check((await fetch(`${base}viewer.js?token=0000000000000000`)).status === 403, 'an asset with a wrong token is refused (403)');

  browser = await launch(puppeteer);
  const page = await browser.newPage();
  await page.setViewport({ width: 900, height: 720 });
  const consoleErrors = watchConsole(page);
  const response = await page.goto(url);
  check(response.status() === 200, 'the page loads with the token');
  const finalCount = () => page.evaluate(() => window.hybViewer.metrics().filter((m) => m.quality === 'final').length);
  await page.waitForFunction(() => window.hybViewer && window.hybViewer.lastFinal(), { timeout: 120000 });
  check(true, 'a first final frame arrives');
  // The first view is anterior: the marker puts the patient's left on the right, superior up,
  // anterior towards the viewer (as DICOM's LPS and `render --marker on` have it).
  const marker = Object.fromEntries((await page.evaluate(() => window.hybViewer.marker())).map((l) => [l.letter, l]));
  check(marker.L.x > 60 && Math.abs(marker.L.y - 42) < 1 && marker.S.y < 20 && marker.A.depth < -0.99,
    `the orientation marker of the anterior view (L at ${marker.L.x.toFixed(0)},${marker.L.y.toFixed(0)}, S at y ${marker.S.y.toFixed(0)}, A's depth ${marker.A.depth.toFixed(2)})`);

  // Orbit: a drag across the canvas.
  const box = await (await page.$('#view')).boundingBox();
  const before = (await page.evaluate(() => window.hybViewer.metrics())).length;
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.down();
  // 25 moves 40 ms apart, then on (back and forth) until two interactive frames came: a slow build
  // (sanitizers) makes fewer frames in the same time.
  const interactiveSince = () => page.evaluate((n) => window.hybViewer.metrics().slice(n).filter((m) => m.quality === 'interactive').length, before);
  const dragStart = Date.now();
  for (let i = 1; i <= 25 || ((await interactiveSince()) < 2 && Date.now() - dragStart < 60000); ++i) {
    const k = 1 + ((i - 1) % 50 < 25 ? (i - 1) % 25 : 24 - ((i - 1) % 25));
    await page.mouse.move(box.x + box.width / 2 + 6 * k, box.y + box.height / 2 + 2 * k);
    await new Promise((r) => setTimeout(r, 40));
  }
  await page.mouse.up();
  await page.waitForFunction((n) => window.hybViewer.metrics().length > n + 2, { timeout: 60000 }, before);
  const interactive = (await page.evaluate(() => window.hybViewer.metrics())).slice(before).filter((m) => m.quality === 'interactive');
  check(interactive.length >= 2, `interactive frames arrive while dragging (${interactive.length})`);

  // A preset and the isosurface at another value.
  await page.select('#preset', 'ct-bone');
  await page.click('#surface-on');
  await page.evaluate(() => {
    const iso = document.getElementById('iso');
    iso.value = 300;
    iso.dispatchEvent(new Event('input'));
    iso.dispatchEvent(new Event('change'));
  });
  await page.waitForFunction(() => {
    const f = window.hybViewer.lastFinal();
    return f && f.command && f.command.includes('--iso 300') && f.command.includes('--preset ct-bone');
  }, { timeout: 120000 });
  const final = await page.evaluate(() => window.hybViewer.lastFinal());
  check(final.format === 'png', 'the final frame is lossless (PNG)');
  check(final.camera.eye.length === 3, 'the final frame carries its camera');
  // Ready at full resolution, then simplified for moving frames: the page says so, then just ready.
  const simplified = await page.waitForFunction(() => document.getElementById('surface-state').textContent === '300 ready', { timeout: 60000 })
    .then(() => true, () => false);
  check(simplified, `the surface's state ends as '300 ready' (${await page.evaluate(() => document.getElementById('surface-state').textContent)})`);

  // The command line the page shows renders the same image as the page's last final frame.
  const renderedPsnr = async (name) => {
    const shown = await page.evaluate(() => window.hybViewer.lastFinal());
    fs.writeFileSync(path.join(tmp, `${name}_viewer.png`), Buffer.from(await page.evaluate(() => window.hybViewer.lastFinalPng()), 'base64'));
    const args = shown.command.match(/'[^']*'|\S+/g).map((a) => a.replace(/^'|'$/g, ''));
    check(args[0] === 'hybrid-octree' && args[1] === 'render', 'the page shows a render command');
    args[args.indexOf('-o') + 1] = path.join(tmp, `${name}_render.png`);
    execFileSync(exe, [...args.slice(1), '--progress', 'off'], { stdio: ['ignore', 'ignore', 'inherit'] });
    const compare = execFileSync(exe, ['compare', path.join(tmp, `${name}_render.png`), path.join(tmp, `${name}_viewer.png`)]).toString();
    const m = compare.match(/PSNR (\S+) dB/);
    return compare.includes('identical') ? Infinity : m ? Number(m[1]) : NaN;
  };
  const psnr = await renderedPsnr('surface');
  check(psnr >= 40, `the final frame equals hybrid-octree render of the same command (PSNR ${psnr} dB, at least 40)`);
  check((await finalCount()) >= 2, 'a final frame follows each settled change');

  // Pre-integrated classification: the final frame's command asks for it and makes the same image.
  await page.click('#preintegrated');
  await page.waitForFunction(() => {
    const f = window.hybViewer.lastFinal();
    return f && f.command && f.command.includes('--classification preintegrated');
  }, { timeout: 120000 });
  const prePsnr = await renderedPsnr('preintegrated');
  check(prePsnr >= 40, `the pre-integrated final frame equals hybrid-octree render of its command (PSNR ${prePsnr} dB, at least 40)`);

  if (screenshot) await page.screenshot({ path: screenshot });

  // The controls refuse what they cannot use and say so.
  const form = await page.evaluate(() => {
    const $ = (id) => document.getElementById(id);
    const out = {};
    const typeIso = (text) => { $('iso-number').value = text; $('iso-number').dispatchEvent(new Event('change')); };
    typeIso('');  // what a number box holds after letters are typed
    out.emptyKept = $('iso').value === '300' && $('iso-number').value === '300';
    out.emptyMessage = $('message').textContent;
    typeIso('99999');
    out.clamped = $('iso-number').value === $('iso').max && $('iso').value === $('iso').max;
    out.clampMessage = $('message').textContent;
    typeIso('-99999');  // the data's smallest value makes no surface: the box stops one above it
    out.lowClamped = $('iso').value === $('iso').min && $('message').textContent.includes(`a surface needs ${$('iso').min} to`);
    typeIso('300');
    // A volume-of-interest minimum moved past its maximum pushes it along.
    const min = $('voi-min-0'), max = $('voi-max-0');
    min.value = Number(max.value) + 20;
    min.dispatchEvent(new Event('input'));
    out.voiOrdered = Number(max.value) === Number(min.value);
    return out;
  });
  check(form.emptyKept && form.emptyMessage.includes('expected a number'), `an isovalue that is not a number is refused and the old one kept (${form.emptyMessage})`);
  check(form.lowClamped, 'an isovalue below the data is clamped to one above its smallest value');
  check(form.clamped && form.clampMessage.includes('using'), `an isovalue beyond the data is clamped and the box shows it (${form.clampMessage})`);
  check(form.voiOrdered, 'the volume of interest keeps its minimum below its maximum');
  // The transfer-function editor puts a point where it is double-clicked, whatever the opacity scale.
  await page.evaluate(() => { const o = document.getElementById('opacity'); o.value = 0.3; o.dispatchEvent(new Event('input')); });
  const tfBox = await (await page.$('#tf-editor')).boundingBox();
  const pointsBefore = (await page.evaluate(() => window.hybViewer.tfPoints())).length;
  await page.mouse.click(tfBox.x + tfBox.width * 0.37, tfBox.y + tfBox.height * 0.25, { clickCount: 2 });
  const added = (await page.evaluate(() => window.hybViewer.tfPoints())).map((p) => p[4]);
  const expected = (110 - 4 - 0.25 * 110) / (110 - 8);  // the editor's y of that click, as an opacity
  check(added.length === pointsBefore + 1 && added.some((a) => Math.abs(a - expected) < 0.02),
    `a double-click adds a point at the clicked opacity with the opacity scale at 0.3 (${added.map((a) => a.toFixed(2)).join(' ')}; ${expected.toFixed(2)} expected)`);

  // Another browser context without the cookie: the page is refused.
  const other = await browser.createBrowserContext();
  const stranger = await other.newPage();
  const refused = await stranger.goto(base);
  check(refused.status() === 403, 'a browser without the token gets 403');
  await other.close();

  check(consoleErrors.length === 0, `the console shows no errors${consoleErrors.length ? ': ' + consoleErrors.join(' | ') : ''}`);
} catch (e) {
  check(false, e.message);
} finally {
  if (browser) await browser.close();
  server.kill('SIGTERM');
  fs.rmSync(tmp, { recursive: true, force: true });
}
console.log(failures() ? `viewer_e2e: ${failures()} failed` : 'viewer_e2e: all passed');
process.exit(failures() ? 1 : 0);
