// End-to-end: `cellinject serve` in Debian's headless Chromium, driven by playwright-core.
//
//   node dashboard.mjs URL [SCREENSHOT_DIR [CELLS]]
//
// Loads the page, checks the plate map's well labels ([row, col] from 0), sees frames arrive (and counts them while a run goes), starts a run
// on the twin, waits for the pipette to be in a cell's procedure, presses ABORT, and
// checks through the API that the pipette is retracted and the run recorded aborted.
// With SCREENSHOT_DIR, the page is photographed once CELLS cells are done (default 1)
// and again after the abort. Prints one JSON line of what it measured; exit 1 on a
// failed check.
import { chromium } from 'playwright-core';

const [url, shots, cellsArg] = process.argv.slice(2);
if (!url) {
  console.error('usage: node dashboard.mjs URL [SCREENSHOT_DIR [CELLS]]');
  process.exit(2);
}
const cells = Number(cellsArg || 1);
const api = async (path, method = 'GET') => {
  const r = await fetch(new URL(path, url), { method });
  return { status: r.status, body: await r.json() };
};
const fail = (what) => { throw new Error(what); };
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
    '--disable-background-networking', '--disable-component-update', '--disable-sync'],
});
const out = {};
try {
  const page = await browser.newPage({ viewport: { width: 1400, height: 1100 } });
  const problems = [];
  page.on('pageerror', (e) => problems.push(String(e)));
  page.on('console', (m) => { if (m.type() === 'error') problems.push(m.text()); });
  await page.goto(url);
  await page.waitForFunction(() => window.cellinject && window.cellinject.frames >= 5, null, { timeout: 20000 });
  await page.waitForFunction(() => window.cellinject.status && window.cellinject.status.state === 'idle', null, { timeout: 5000 });

  // The plate map numbers wells as the files and the command line do: [row, col] from 0.
  await page.waitForFunction(() => window.cellinject.plateLabels, null, { timeout: 5000 });
  out.plate_labels = await page.evaluate(() => window.cellinject.plateLabels);
  const want = (n) => Array.from({ length: n }, (_, i) => String(i));
  const st0 = (await api('/api/status')).body;
  if (JSON.stringify(out.plate_labels.rows) !== JSON.stringify(want(st0.plate.rows))
    || JSON.stringify(out.plate_labels.cols) !== JSON.stringify(want(st0.plate.cols))) {
    fail(`the plate map's labels are ${JSON.stringify(out.plate_labels)}, not rows and columns from 0`);
  }

  await page.click('#start');
  // The run goes: wait for the pipette to work on a cell (A3 driven forward).
  await page.waitForFunction(() => {
    const s = window.cellinject.status;
    return s && s.state === 'running' && s.run && s.run.current !== null && s.actuators_v[2] > 0;
  }, null, { timeout: 240000, polling: 20 });
  // Frames while the run goes: counted by the page as they are drawn.
  const f0 = await page.evaluate(() => window.cellinject.frames);
  const t0 = Date.now();
  await sleep(3000);
  const f1 = await page.evaluate(() => window.cellinject.frames);
  out.fps_during_run = (f1 - f0) / ((Date.now() - t0) / 1000);
  if (out.fps_during_run < 10) fail(`the live view showed ${out.fps_during_run.toFixed(1)} frames/s during the run (< 10)`);

  if (shots) {
    await page.waitForFunction((n) => {
      const s = window.cellinject.status;
      return s && s.run && s.run.done >= n && s.run.current !== null && s.actuators_v[2] > 0;
    }, cells, { timeout: 600000, polling: 20 });
    await sleep(300);
    await page.screenshot({ path: `${shots}/dashboard-run.png` });
    const view = await page.$('#view');
    await view.screenshot({ path: `${shots}/dashboard-view.png` });
  }

  // ABORT while the pipette is at a cell. The A3 voltage reported is the one the wait
  // saw (a later read may already see the next status, with the pipette withdrawn).
  const seen = await page.waitForFunction(() => {
    const s = window.cellinject.status;
    return s && s.run && s.run.current !== null && s.actuators_v[2] > 0 ? s.actuators_v[2] : false;
  }, null, { timeout: 60000, polling: 10 });
  out.a3_volts_before_abort = await seen.jsonValue();
  const ta = Date.now();
  await page.click('#abort');
  let st;
  for (;;) {
    st = (await api('/api/status')).body;
    if (st.state === 'aborted') break;
    if (Date.now() - ta > 1000) fail(`state ${st.state} 1 s after abort`);
    await sleep(20);
  }
  out.aborted_after_s = (Date.now() - ta) / 1000;
  for (;;) {
    st = (await api('/api/status')).body;
    if (st.task === null && !st.stopping) break;
    if (Date.now() - ta > 10000) fail(`still ${st.task} 10 s after abort`);
    await sleep(20);
  }
  out.safe_after_s = (Date.now() - ta) / 1000;
  if (st.state !== 'aborted') fail(`state ${st.state} after the abort`);
  if (!st.retracted || st.actuators_v[2] !== 0) fail(`A3 not retracted: ${st.actuators_v}`);
  if (!st.safe) fail(`not in the safe state: ${st.actuators_v}`);
  out.actuators_after_v = st.actuators_v;
  out.cells_done = st.run.done;
  const runs = (await api('/api/runs')).body;
  if (!runs.length || runs[0].status !== 'aborted') fail(`the run is recorded ${runs.length ? runs[0].status : 'nowhere'}`);
  out.recorded = runs[0].status;
  out.run_id = runs[0].id;
  // The page shows it too.
  await page.waitForFunction(() => {
    const s = window.cellinject.status;
    return document.getElementById('state').textContent === 'aborted' && s.task === null && s.safe;
  }, null, { timeout: 3000 });
  if (shots) {
    await sleep(700); // a few more frames and statuses: the view after the lift
    await page.screenshot({ path: `${shots}/dashboard-aborted.png` });
  }
  // The run's report opens from the records table.
  const report = await fetch(new URL(`/runs/${out.run_id}`, url));
  if (report.status !== 200 || !(await report.text()).includes('aborted')) fail('the run report');
  if (problems.length) fail(`the page reported errors: ${problems.join('; ')}`);
  out.ok = true;
  console.log(JSON.stringify(out));
} catch (e) {
  out.ok = false;
  out.error = String(e && e.message || e);
  console.log(JSON.stringify(out));
  process.exitCode = 1;
} finally {
  await browser.close();
}
