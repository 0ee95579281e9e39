// The viewer's targets, measured from a real browser: a scripted five-second orbit of a volume (the
// cranium by default; 512² view), volume only and with a translucent isosurface. Reports the frames per second
// painted, the latency from the input message to the frame painted (p50, p95), the quality levels
// used, the bytes per frame, the PSNR of interactive frames (as painted, upscaled) against the
// reference ray tracer, and the time from the end of the motion to the final frame painted.
//
// usage (after scripts/setup.sh): node bench/viewer_bench.mjs build/hybrid-octree [--seconds 5] [--samples 4] [--frame-ms 80]
//                                  [--volume FILE] [--iso V]   (default: the cranium and 400 HU)
//                                  [--volume-only]   (no surface orbit: a study too large to extract one from)
//                                  [--surface-only]  (no volume orbit)
//                                  [--frames]   (also print each interactive frame's level, time and bricks drawn coarser)
//                                  [--server-args 'ARGS']   (more flags for the server, e.g. '--texture-mb 1024')
import { spawn, execFileSync } from 'node:child_process';
import { createRequire } from 'node:module';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';

const require = createRequire(path.resolve('tests/e2e/package.json'));
const puppeteer = require('puppeteer-core');

const exe = path.resolve(process.argv[2] || 'build/hybrid-octree');
const text = (name, dflt) => { const i = process.argv.indexOf(name); return i > 0 ? process.argv[i + 1] : dflt; };
const arg = (name, dflt) => Number(text(name, dflt));
const seconds = arg('--seconds', 5), samples = arg('--samples', 4), frameMs = arg('--frame-ms', 80), iso = arg('--iso', 400);
const volume = path.resolve(text('--volume', '/usr/share/doc/invesalius-examples/examples/Cranium.inv3'));
if (!fs.existsSync(volume)) { console.error(`viewer_bench: --volume ${volume} does not exist`); process.exit(2); }
if (!Number.isFinite(iso)) { console.error('viewer_bench: --iso must be a number (data units)'); process.exit(2); }
const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'hyb-viewer-bench-'));

// The browser first, as a user's is already running: launched with the server, its start-up shared
// the two cores with the scene's first frame.
const browser = await puppeteer.launch({ executablePath: '/usr/bin/chromium', headless: true, args: ['--no-sandbox', '--disable-gpu'] });
const page = await browser.newPage();
await page.setViewport({ width: 900, height: 720 });
const serverArgs = text('--server-args', '').split(' ').filter((a) => a);
const server = spawn(exe, ['view', volume, '--port', '0', '--progress', 'off', '--frame-ms', String(frameMs), ...serverArgs], { stdio: ['ignore', 'pipe', 'inherit'] });
const url = await new Promise((resolve, reject) => {
  let out = '';
  server.stdout.on('data', (d) => { out += d; const m = out.match(/(http:\/\/\S+\?token=[0-9a-f]+)/); if (m) resolve(m[1]); });
  server.on('exit', (code) => reject(new Error(`server exited (${code})`)));
});
await page.goto(url);
await page.waitForFunction(() => window.hybViewer && window.hybViewer.lastFinal(), { timeout: 120000 });
{
  // (painted times are the page's performance.now(): milliseconds since it began to load)
  const opened = await page.evaluate(() => { const m = window.hybViewer.metrics(); return [m[0].paintedAt, m.find((f) => f.quality === 'final').paintedAt, m[0].levelText, m[0].renderMs]; });
  console.log(`opening: the first frame (${opened[2]}, render ${opened[3].toFixed(0)} ms) painted ${opened[0].toFixed(0)} ms after the page began to load, the final frame ${opened[1].toFixed(0)} ms`);
}

const quantile = (xs, q) => { const s = [...xs].sort((a, b) => a - b); return s[Math.min(s.length - 1, Math.floor(q * s.length))]; };

async function waitFinal(predicate = 'true', timeout = 120000) {
  const before = await page.evaluate(() => window.hybViewer.metrics().filter((m) => m.quality === 'final').length);
  await page.waitForFunction(`window.hybViewer.metrics().filter((m) => m.quality === 'final').length > ${before} && (${predicate})`, { timeout });
}

function reference(header, withSurface, file, size) {
  const c = header.camera;
  const args = ['render', volume, '--renderer', 'raycast', '--eye', c.eye.join(','), '--center', c.center.join(','), '--up', c.up.join(','),
    '--fov', String(c.fov), '--size', size, '--preset', 'ct-skin-bone', '--progress', 'off', '-o', file];
  if (withSurface) args.push('--iso', String(iso), '--surface-color', '0.9490196078431372,0.9215686274509803,0.8509803921568627,0.5');
  execFileSync(exe, args, { stdio: 'ignore' });
}

function psnrOf(a, b) {
  const out = execFileSync(exe, ['compare', a, b]).toString();
  if (out.includes('identical')) return Infinity;
  return Number(out.match(/PSNR (\S+) dB/)[1]);
}

// The reference rendered at a frame's own size and magnified as the page magnifies frames: the
// most any frame of that size can score as painted.
async function magnified(file, out, width, height) {
  const png = fs.readFileSync(file).toString('base64');
  const data = await page.evaluate(async (png, width, height) => {
    // From bytes, not a data: URL, which the page's content security policy refuses to fetch.
    const bytes = Uint8Array.from(atob(png), (c) => c.charCodeAt(0));
    const bitmap = await createImageBitmap(new Blob([bytes], { type: 'image/png' }));
    const canvas = new OffscreenCanvas(width, height), ctx = canvas.getContext('2d');
    ctx.imageSmoothingEnabled = true;
    ctx.imageSmoothingQuality = 'low';
    ctx.drawImage(bitmap, 0, 0, width, height);
    const blob = await canvas.convertToBlob({ type: 'image/png' });
    return await new Promise((resolve) => {
      const reader = new FileReader();
      reader.onload = () => resolve(reader.result.split(',')[1]);
      reader.readAsDataURL(blob);
    });
  }, png, width, height);
  fs.writeFileSync(out, Buffer.from(data, 'base64'));
}

async function orbit(label, withSurface) {
  const box = await (await page.$('#view')).boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  const t0 = await page.evaluate(() => performance.now());
  const start = Date.now();
  const shots = [];
  let nextShot = 1000 * seconds / (samples + 1);
  for (let i = 0; Date.now() - start < 1000 * seconds; ++i) {
    // A steady drag: 4 px every 16 ms, swinging back and forth so the head stays in view.
    const phase = ((Date.now() - start) / 1000) * Math.PI * 0.8;
    await page.mouse.move(cx + 160 * Math.sin(phase), cy + 30 * Math.sin(2 * phase), { steps: 1 });
    await new Promise((r) => setTimeout(r, 16));
    if (Date.now() - start > nextShot && shots.length < samples) {
      shots.push(await page.evaluate(async () => window.hybViewer.snapshot()));
      nextShot += 1000 * seconds / (samples + 1);
    }
  }
  const tUp = await page.evaluate(() => performance.now());
  await page.mouse.up();
  await waitFinal();
  const metrics = await page.evaluate(() => window.hybViewer.metrics());
  const during = metrics.filter((m) => m.paintedAt > t0 && m.paintedAt <= tUp + 1);
  const interactive = during.filter((m) => m.quality === 'interactive');
  const final = metrics.filter((m) => m.quality === 'final' && m.paintedAt > tUp).at(0);
  const latencies = interactive.map((m) => m.latencyMs).filter((x) => x !== null);
  const levels = {};
  for (const m of interactive) {
    const l = (levels[m.levelText] ||= { n: 0, ms: 0 });
    l.n++;
    l.ms += m.renderMs + m.encodeMs;
  }
  const painted = [], sent = [], bound = [];
  for (const [k, s] of shots.entries()) {
    if (!s.header || s.header.quality !== 'interactive') continue;
    const shot = path.join(tmp, `${label}-${k}.png`), ref = path.join(tmp, `${label}-${k}-ref.png`);
    fs.writeFileSync(shot, Buffer.from(s.png.split(',')[1], 'base64'));
    reference(s.header, withSurface, ref, `${s.header.camera.size[0]}x${s.header.camera.size[1]}`);
    painted.push(psnrOf(ref, shot));
    // The frame as sent, at its own size, against the reference at that size.
    const own = path.join(tmp, `${label}-${k}-own.png`), ownRef = path.join(tmp, `${label}-${k}-ownref.png`);
    fs.writeFileSync(own, Buffer.from(s.frame, 'base64'));
    reference(s.header, withSurface, ownRef, `${s.header.width}x${s.header.height}`);
    sent.push(`${psnrOf(ownRef, own).toFixed(1)} (${s.header.width}²)`);
    const ownRefMagnified = path.join(tmp, `${label}-${k}-ownref-magnified.png`);
    await magnified(ownRef, ownRefMagnified, s.header.camera.size[0], s.header.camera.size[1]);
    bound.push(psnrOf(ref, ownRefMagnified));
  }
  const bytes = interactive.map((m) => m.bytes);
  console.log(`${label}:`);
  console.log(`  frames painted in ${seconds} s: ${during.length} (${(during.length / seconds).toFixed(1)} frames/s; target >= 10)`);
  console.log(`  latency input -> painted: p50 ${quantile(latencies, 0.5).toFixed(0)} ms, p95 ${quantile(latencies, 0.95).toFixed(0)} ms (target p95 <= 150)`);
  const med = (f) => quantile(interactive.map(f), 0.5).toFixed(0);
  console.log(`  latency parts (medians): request to the server ${med((m) => m.upMs)} ms, waiting for the render thread ${med((m) => m.waitMs)}, ` +
    `render ${med((m) => m.renderMs)}, encode ${med((m) => m.encodeMs)}, frame to the page ${med((m) => m.downMs)}, decode and paint ${med((m) => m.paintMs)}`);
  const coarser = interactive.filter((m) => m.bricksNotResident > 0);
  console.log(`  frames drawing bricks coarser (textures beyond the packing bound, or knots the store is loading): ${coarser.length} of ${interactive.length}` +
    (coarser.length ? ` (median ${quantile(coarser.map((m) => m.bricksNotResident), 0.5).toFixed(0)} bricks)` : ''));
  console.log(`  levels used: ${Object.entries(levels).map(([k, l]) => `${k}: ${l.n} frames, ${(l.ms / l.n).toFixed(0)} ms`).join('; ')}`);
  if (process.argv.includes('--frames'))
    console.log(`  frames in order (level: render + encode ms, bricks coarser): ${interactive.map((m) => `${m.level}: ${(m.renderMs + m.encodeMs).toFixed(0)}${m.bricksNotResident ? ` (${m.bricksNotResident})` : ''}`).join(', ')}`);
  console.log(`  bytes per interactive frame: mean ${(bytes.reduce((a, b) => a + b, 0) / Math.max(1, bytes.length) / 1024).toFixed(1)} KiB; final ${final ? (final.bytes / 1024).toFixed(1) : '?'} KiB`);
  console.log(`  interactive frames against the reference, as painted (512²): ${painted.map((p) => p.toFixed(1)).join(', ')} dB (target >= 30)`);
  console.log(`  the same frames as sent, at their own size: ${sent.join(', ')} dB`);
  console.log(`  the reference at each frame's size, magnified as painted (the most a frame of that size can score): ${bound.map((p) => p.toFixed(1)).join(', ')} dB`);
  console.log(`  final frame painted ${final ? (final.paintedAt - tUp).toFixed(0) : '?'} ms after the motion stopped (target <= 2000)`);
  const after = metrics.filter((m) => m.paintedAt > tUp && m.paintedAt <= (final ? final.paintedAt : Infinity));
  console.log(`  frames after the motion: ${after.map((m) => `${m.quality} ${m.levelText} at +${(m.paintedAt - tUp).toFixed(0)} ms (render ${m.renderMs.toFixed(0)} + encode ${m.encodeMs.toFixed(0)} ms, ` +
    `${(m.textureBytes / 1048576).toFixed(0)} MB of textures${m.bricksNotResident ? `, ${m.bricksNotResident} bricks coarser` : ''})`).join('; ')}`);
}

try {
  await page.evaluate(() => { document.getElementById('surface-on').checked = false; });
  await page.evaluate(() => window.hybViewer.request(false));
  await waitFinal();
  if (!process.argv.includes('--surface-only')) await orbit('volume only', false);
  if (!process.argv.includes('--volume-only')) {
    await page.evaluate((v) => { document.getElementById('iso').value = document.getElementById('iso-number').value = String(v); }, iso);
    const asked = await page.evaluate(() => performance.now());
    await page.click('#surface-on');
    // The orbit starts once the full-resolution surface is drawn (not its preview, built beside the frames).
    await waitFinal(`window.hybViewer.lastFinal().iso === ${iso} && window.hybViewer.lastFinal().surfaceReady`, 600000);
    const frames = (await page.evaluate(() => window.hybViewer.metrics())).filter((m) => m.paintedAt > asked && m.iso === iso);
    const first = frames[0], full = frames.find((m) => m.surfaceReady);
    // Moving frames draw the preview until the builder has simplified the full surface for them:
    // the orbit measures the frames after, a moving frame asked for every 300 ms till then.
    let simplified = null;
    for (const until = Date.now() + 600000; simplified === null && Date.now() < until;) {
      await page.evaluate(() => window.hybViewer.request(true));
      await new Promise((r) => setTimeout(r, 300));
      const moving = (await page.evaluate(() => window.hybViewer.metrics())).filter((m) => m.quality === 'interactive' && m.iso === iso).at(-1);
      if (moving && !moving.surfaceBuilding) simplified = moving.paintedAt - asked;
    }
    await page.evaluate(() => window.hybViewer.request(false));
    await waitFinal(`window.hybViewer.lastFinal().iso === ${iso}`);
    console.log(`surface ${iso} asked for: first drawn after ${first ? (first.paintedAt - asked).toFixed(0) : '?'} ms` +
      `${first && !first.surfaceReady ? ' (its clustered preview)' : ''}, at full resolution after ${full ? (full.paintedAt - asked).toFixed(0) : '?'} ms` +
      `, simplified for moving frames after ${simplified === null ? '?' : simplified.toFixed(0)} ms`);
    await orbit(`volume + translucent surface (${iso}, alpha 0.5)`, true);
  }
} finally {
  await browser.close();
  server.kill('SIGTERM');
  fs.rmSync(tmp, { recursive: true, force: true });
}
