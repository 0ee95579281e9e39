// What the viewer's browser tests share: the server started on a free port (its printed URL with
// the token), Debian's chromium through puppeteer-core, and a checklist that counts failures.
import { spawn } from 'node:child_process';
import path from 'node:path';

export const chromium = process.env.CHROMIUM || '/usr/bin/chromium';

export async function loadPuppeteer() {
  try {
    return (await import('puppeteer-core')).default;
  } catch {
    console.error('viewer e2e: puppeteer-core is missing (npm ci --prefix tests/e2e; scripts/setup.sh does it)');
    process.exit(1);
  }
}

// Starts `EXE view ARGS --port 0 --progress off`; resolves with the server and the URL it prints.
export function startServer(exe, args) {
  const server = spawn(path.resolve(exe), ['view', ...args, '--port', '0', '--progress', 'off'], { stdio: ['ignore', 'pipe', 'inherit'] });
  const url = new Promise((resolve, reject) => {
    let out = '';
    const timer = setTimeout(() => reject(new Error('the server printed no URL within 120 s')), 120000);
    server.stdout.on('data', (d) => {
      out += d;
      const m = out.match(/(http:\/\/\S+\?token=[0-9a-f]+)/);
      if (m) { clearTimeout(timer); resolve(m[1]); }
    });
    server.on('exit', (code) => reject(new Error(`the server exited (${code}) before printing its URL`)));
  });
  return { server, url };
}

export async function launch(puppeteer) {
  return puppeteer.launch({ executablePath: chromium, headless: true, args: ['--no-sandbox', '--disable-gpu', '--disable-dev-shm-usage'] });
}

// A checklist: check(ok, what) prints each line; failures() counts those that failed.
export function checklist() {
  let failed = 0;
  return {
    check(ok, what) {
      console.log(`${ok ? 'ok  ' : 'FAIL'} ${what}`);
      if (!ok) failed++;
    },
    failures: () => failed,
  };
}

// Collects the page's console errors and uncaught exceptions.
export function watchConsole(page) {
  const errors = [];
  page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
  page.on('pageerror', (e) => errors.push(e.message));
  return errors;
}

// One DICOM data element, explicit VR little endian as PS3.5 lays it out (values padded to even length).
export function dicomElement(group, element, vr, value) {
  let v = Buffer.isBuffer(value) ? value : Buffer.from(value, 'latin1');
  if (v.length % 2) v = Buffer.concat([v, Buffer.from(vr === 'UI' || vr === 'OB' ? '\0' : ' ')]);
  const long = vr === 'OB' || vr === 'OW';
  const h = Buffer.alloc(long ? 12 : 8);
  h.writeUInt16LE(group, 0);
  h.writeUInt16LE(element, 2);
  h.write(vr, 4, 'latin1');
  if (long) h.writeUInt32LE(v.length, 8);
  else h.writeUInt16LE(v.length, 6);
  return Buffer.concat([h, v]);
}

// A PS3.10 file of the CT image @p instance (SOP Instance UID) whose data set's elements, in tag
// order, are @p data: the preamble, DICM and the file meta information.
export function dicomFile(instance, data) {
  const ct = '1.2.840.10008.5.1.4.1.1.2';
  const metaBody = Buffer.concat([dicomElement(2, 1, 'OB', Buffer.from([0, 1])), dicomElement(2, 2, 'UI', ct), dicomElement(2, 3, 'UI', instance),
    dicomElement(2, 0x10, 'UI', '1.2.840.10008.1.2.1')]);
  const groupLength = Buffer.alloc(4);
  groupLength.writeUInt32LE(metaBody.length);
  return Buffer.concat([Buffer.alloc(128), Buffer.from('DICM'), dicomElement(2, 0, 'UL', groupLength), metaBody, data]);
}
