// Browser test of the replay page (docs/replay.md), run by tests/browser_replay.sh (ctest
// Browser.Replay): Debian's chromium driven headless by playwright-core, WebGL by SwiftShader.
//   node replay.test.mjs UKDYN SOURCE_DIR SCRATCH_DIR
// Checks: the page opens with every network request refused (only the file itself is let through),
// no console error; the canvas is not blank; two screenshots of the same frame are identical; the
// pixel centroid of one marker at the left arm's cut point follows the simulated coordinate,
// computed here from trajectory.csv's q by the paper's closed form (not by ukdyn's geometry code)
// and projected through the page's camera. Then the free-body load of n_robots_4_weld.yaml: the
// drawn box's corners against the inertia-equivalent box computed here from the scenario's mass and
// inertia, posed by the CSV's load_x..load_qz, and the red pixels' centroid of the box alone against
// the projection of the CSV's load position, at the first and the last frame.
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import path from 'node:path';
import zlib from 'node:zlib';
import { pathToFileURL } from 'node:url';
import { chromium } from 'playwright-core';

const [ukdyn, source, scratch] = process.argv.slice(2);
const started = Date.now();
const fail = (msg) => { console.error(`FAIL: ${msg}`); process.exit(1); };
const check = (ok, msg) => { if (!ok) fail(msg); console.log(`ok: ${msg}`); };

// ---- the run: the paper's scenario, with its page
const out = path.join(scratch, 'paper');
fs.rmSync(out, { recursive: true, force: true });
execFileSync(ukdyn, ['simulate', path.join(source, 'scenarios/paper.yaml'), '--out', out, '--no-figures', '--html', '--quiet'], { stdio: 'inherit' });
const file = path.join(out, 'replay.html');
const bytes = fs.statSync(file).size;
console.log(`page: ${file}, ${(bytes / 1e6).toFixed(2)} MB (${((Date.now() - started) / 1000).toFixed(1)} s for the run)`);

// trajectory.csv → columns by name
const lines = fs.readFileSync(path.join(out, 'trajectory.csv'), 'utf8').trim().split('\n');
const header = lines[0].split(',');
const rows = lines.slice(1).map((l) => l.split(',').map(Number));
const col = (n) => { const i = header.indexOf(n); if (i < 0) fail(`no column ${n}`); return rows.map((r) => r[i]); };
// The paper's arm (scenarios/paper.yaml, Table 1: l_r = 0.5, l = 0.7, 0.8, 0.4): the cut point is
// (Δx + κ cos δ, Δy + κ sin δ, l_r + ρ) with κ = Σ l_k cos θ_k, ρ = Σ l_k sin θ_k (paper Eq. (12)).
const [dx, dy, de, t1, t2, t3] = ['dx1', 'dy1', 'delta1', 'theta1', 'theta2', 'theta3'].map(col);
const L = [0.7, 0.8, 0.4];
const cut = (i) => {
  const th = [t1[i], t2[i], t3[i]];
  const kappa = th.reduce((s, a, k) => s + L[k] * Math.cos(a), 0);
  const rho = th.reduce((s, a, k) => s + L[k] * Math.sin(a), 0);
  return [dx[i] + kappa * Math.cos(de[i]), dy[i] + kappa * Math.sin(de[i]), 0.5 + rho];
};

// ---- minimal PNG decoder (8-bit RGB/RGBA, not interlaced: what Chromium's screenshots are)
function decodePng(buf) {
  let pos = 8, w = 0, h = 0, ch = 0;
  const idat = [];
  while (pos < buf.length) {
    const len = buf.readUInt32BE(pos), type = buf.toString('ascii', pos + 4, pos + 8);
    const data = buf.subarray(pos + 8, pos + 8 + len);
    if (type === 'IHDR') {
      w = data.readUInt32BE(0); h = data.readUInt32BE(4);
      if (data[8] !== 8 || data[12] !== 0) fail('unexpected PNG format');
      ch = { 2: 3, 6: 4 }[data[9]];
      if (!ch) fail(`unexpected PNG colour type ${data[9]}`);
    } else if (type === 'IDAT') idat.push(data);
    pos += 12 + len;
  }
  const raw = zlib.inflateSync(Buffer.concat(idat));
  const px = Buffer.alloc(w * h * 4), stride = w * ch;
  let prev = Buffer.alloc(stride), p = 0;
  for (let y = 0; y < h; y++) {
    const f = raw[p++], line = Buffer.from(raw.subarray(p, p + stride)); p += stride;
    for (let x = 0; x < stride; x++) {
      const a = x >= ch ? line[x - ch] : 0, b = prev[x], c = x >= ch ? prev[x - ch] : 0;
      const pa = Math.abs(b - c), pb = Math.abs(a - c), pc = Math.abs(a + b - 2 * c);
      const pred = [0, a, b, (a + b) >> 1, pa <= pb && pa <= pc ? a : pb <= pc ? b : c][f];
      line[x] = (line[x] + pred) & 255;
    }
    for (let x = 0; x < w; x++) {
      for (let k = 0; k < 3; k++) px[4 * (y * w + x) + k] = line[ch * x + k];
      px[4 * (y * w + x) + 3] = ch === 4 ? line[ch * x + 3] : 255;
    }
    prev = line;
  }
  return { w, h, px };
}

// Weighted centroid of the red pixels of a screenshot (antialiased edges count in part).
function redCentroid(s) {
  let n = 0, sx = 0, sy = 0;
  for (let y = 0; y < s.h; y++) for (let x = 0; x < s.w; x++) {
    const k = 4 * (y * s.w + x);
    const wgt = s.px[k] / 255;
    if (s.px[k + 1] > 40 || s.px[k + 2] > 40 || wgt < 0.05) continue;
    n += wgt; sx += wgt * (x + 0.5); sy += wgt * (y + 0.5);
  }
  return { n, x: sx / n, y: sy / n };
}

// The free-body load of scenarios/n_robots_4_weld.yaml: drawn, where and how the CSV says.
async function checkFreeBody(context, refused, errors) {
  const yaml = path.join(source, 'scenarios/n_robots_4_weld.yaml');
  const dir = path.join(scratch, 'weld');
  fs.rmSync(dir, { recursive: true, force: true });
  execFileSync(ukdyn, ['simulate', yaml, '--out', dir, '--no-figures', '--html', '--quiet'], { stdio: 'inherit' });
  // mass and inertia (diagonal, body frame) as the scenario declares them
  const m = /- name: load\n\s+type: free_body\n\s+mass: (\S+)\n\s+inertia: \[([^\]]+)\]/.exec(fs.readFileSync(yaml, 'utf8'));
  if (!m) fail('n_robots_4_weld.yaml: no free_body load with mass and diagonal inertia');
  const mass = Number(m[1]), I = m[2].split(',').map(Number);
  // the uniform box of the same mass and moments: I1 = mass (b² + c²) / 12, ...
  const edge = [0, 1, 2].map((i) => Math.sqrt(6 * (I[(i + 1) % 3] + I[(i + 2) % 3] - I[i]) / mass));
  const ls = fs.readFileSync(path.join(dir, 'trajectory.csv'), 'utf8').trim().split('\n');
  const hd = ls[0].split(','), rs = ls.slice(1).map((l) => l.split(',').map(Number));
  const c = (n) => { const i = hd.indexOf(n); if (i < 0) fail(`weld: no column ${n}`); return rs.map((r) => r[i]); };
  const [x, y, z, qw, qx, qy, qz] = ['x', 'y', 'z', 'qw', 'qx', 'qy', 'qz'].map((k) => c(`load_${k}`));
  const quatMatrix = (q4) => {  // R of the normalised quaternion [w, x, y, z]
    const nq = Math.hypot(...q4);
    const [w, a, b, d] = q4.map((v) => v / nq);
    return [[1 - 2 * (b * b + d * d), 2 * (a * b - w * d), 2 * (a * d + w * b)],
      [2 * (a * b + w * d), 1 - 2 * (a * a + d * d), 2 * (b * d - w * a)],
      [2 * (a * d - w * b), 2 * (b * d + w * a), 1 - 2 * (a * a + b * b)]];
  };
  const rotation = (f) => quatMatrix([qw[f], qx[f], qy[f], qz[f]]);  // the load's at frame f
  const mul = (A, B) => A.map((r) => [0, 1, 2].map((j) => r[0] * B[0][j] + r[1] * B[1][j] + r[2] * B[2][j]));
  const rpyMatrix = ([r, p, y]) => {  // Rz(yaw) Ry(pitch) Rx(roll), the scenario's offsets
    const [cr, sr, cp, sp, cy, sy] = [Math.cos(r), Math.sin(r), Math.cos(p), Math.sin(p), Math.cos(y), Math.sin(y)];
    return mul(mul([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]], [[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]), [[1, 0, 0], [0, cr, -sr], [0, sr, cr]]);
  };
  const corners = (f) => {  // centre + R(q) (±a/2, ±b/2, ±c/2)
    const R = rotation(f);
    const out = [];
    for (const sx of [-0.5, 0.5]) for (const sy of [-0.5, 0.5]) for (const sz of [-0.5, 0.5]) {
      const v = [sx * edge[0], sy * edge[1], sz * edge[2]];
      out.push([x[f], y[f], z[f]].map((p, k) => p + R[k][0] * v[0] + R[k][1] * v[1] + R[k][2] * v[2]));
    }
    return out;
  };
  const page = await context.newPage();
  const url = pathToFileURL(path.join(dir, 'replay.html')).href;
  await page.route('**/*', (route) => (route.request().url() === url ? route.continue() : (refused.push(route.request().url()), route.abort())));
  page.on('console', (msg) => { if (msg.type() === 'error') errors.push(`weld: ${msg.text()}`); });
  page.on('pageerror', (e) => errors.push(`weld page error: ${e.message}`));
  await page.goto(url);
  await page.waitForFunction(() => window.ukdyn && window.ukdyn.ready, null, { timeout: 20000 });
  const note = await page.evaluate(() => document.getElementById('note').textContent);
  check(!/\bload\b/.test(note), `the load is not listed as not drawn (note: '${note}')`);
  const last = rs.length - 1;
  let worst = 0, worstPx = 0;
  const seen = [];
  for (const f of [0, last]) {
    const got = await page.evaluate((k) => (window.ukdyn.setFrame(k), window.ukdyn.solid('load')), f);
    if (!got) fail('no solid named load in the page');
    const want = corners(f);
    for (let k = 0; k < 8; k++) worst = Math.max(worst, Math.hypot(...want[k].map((v, j) => v - got.corners[k][j])));
    await page.evaluate(() => window.ukdyn.solidOnly('load'));
    const s = redCentroid(decodePng(await page.locator('#view canvas').screenshot()));
    if (s.n < 100) fail(`frame ${f}: the load's box is not visible (${s.n} px)`);
    const p = await page.evaluate((v) => window.ukdyn.project(v), [x[f], y[f], z[f]]);
    const err = Math.hypot(s.x - p[0], s.y - p[1]);
    worstPx = Math.max(worstPx, err);
    seen.push([s.x, s.y, x[f], y[f], z[f]]);
    console.log(`weld frame ${f}: box centroid (${s.x.toFixed(2)}, ${s.y.toFixed(2)}) px over ${s.n.toFixed(0)} px, CSV load position projected (${p[0].toFixed(2)}, ${p[1].toFixed(2)}), ${err.toFixed(2)} px`);
    await page.evaluate(() => window.ukdyn.solidOnly(null));
  }
  // the grasp frames' axes: at the load's position + R(q) (the weld's offset on the load, from the
  // scenario) at the last frame
  const text = fs.readFileSync(yaml, 'utf8');
  const offsets = [...text.matchAll(/name: (\w+), a: \S+, b: \{frame: load\.load, xyz: \[([^\]]+)\], rpy: \[([^\]]+)\]/g)]
    .map((g) => [g[1], g[2].split(',').map(Number), g[3].split(',').map(Number)]);
  if (offsets.length !== 4) fail(`n_robots_4_weld.yaml: ${offsets.length} welds to the load found, expected 4`);
  const axes = await page.evaluate((k) => (window.ukdyn.setFrame(k), window.ukdyn.frames3d()), last);
  let worstAxes = 0, worstTurn = 0, transposed = Infinity;
  {
    const R = rotation(last);
    for (const [name, o, rpy] of offsets) {
      const got = axes.find((g) => g.name === name);
      if (!got) fail(`no axes drawn for ${name} (${axes.map((g) => g.name).join(', ')})`);
      const want = [x[last], y[last], z[last]].map((p, k) => p + R[k][0] * o[0] + R[k][1] * o[1] + R[k][2] * o[2]);
      worstAxes = Math.max(worstAxes, Math.hypot(...want.map((v, k) => v - got.position[k])));
      // the axes' orientation: the load's R(q) times the weld's rpy on the load (frame b)
      const wantR = mul(R, rpyMatrix(rpy)), gotR = quatMatrix(got.quaternion);
      const dist = (A, B) => Math.hypot(...A.flatMap((r, i) => r.map((v, j) => v - B[i][j])));
      worstTurn = Math.max(worstTurn, dist(gotR, wantR));
      const asym = dist(wantR, wantR[0].map((_, j) => wantR.map((r) => r[j])));  // |R − Rᵀ|
      if (asym > 0.5) transposed = Math.min(transposed, dist(gotR[0].map((_, j) => gotR.map((r) => r[j])), wantR));
    }
  }
  check(worstAxes < 1e-4, `the ${offsets.length} grasp frames' axes within ${worstAxes.toExponential(2)} m of the load pose + the welds' offsets`);
  check(worstTurn < 1e-4 && transposed > 0.5, `their orientations within ${worstTurn.toExponential(2)} of R(q) Rz Ry Rx(rpy) (Frobenius; drawn transposed they would be ${transposed.toFixed(2)} off)`);
  // the internal (squeeze) force of each grasp: an arrow at pose_<c>_x..z along
  // Wint_walker_<c>_fx..fz, its length |f| times the scale the legend states
  const legend = await page.evaluate(() => document.getElementById('squeezeScale')?.textContent ?? '');
  const perMetre = /1 m = (\S+) N/.exec(legend);
  if (!perMetre) fail(`no internal-force scale in the legend ('${legend}')`);
  let worstOrigin = 0, worstDir = 0, worstLen = 0, shown = 0;
  for (const f of [0, Math.floor(last / 2), last]) {
    const sq = await page.evaluate((k) => (window.ukdyn.setFrame(k), window.ukdyn.squeeze()), f);
    check(Math.abs(sq.scale * Number(perMetre[1]) - 1) < 5e-3, `frame ${f}: the arrows' scale ${sq.scale.toExponential(3)} m/N is the legend's (${legend})`);
    for (const [name] of offsets) {
      const a = sq.arrows.find((g) => g.name === name);
      if (!a) fail(`frame ${f}: no internal-force arrow for ${name} (${sq.arrows.map((g) => g.name).join(', ')})`);
      const o = ['x', 'y', 'z'].map((k) => c(`pose_${name}_${k}`)[f]);
      const w = ['fx', 'fy', 'fz'].map((k) => c(`Wint_walker_${name}_${k}`)[f]);
      const n = Math.hypot(...w);
      worstOrigin = Math.max(worstOrigin, Math.hypot(...o.map((v, k) => v - a.origin[k])));
      if (n > 1e-9) {
        worstDir = Math.max(worstDir, Math.hypot(...w.map((v, k) => v / n - a.direction[k])));
        worstLen = Math.max(worstLen, Math.abs(a.length - n / Number(perMetre[1])) / (n / Number(perMetre[1])));
        if (a.visible) shown++;
      }
    }
  }
  check(shown > 0, `${shown} internal-force arrows drawn at 3 frames`);
  check(worstOrigin < 1e-4, `the internal-force arrows start within ${worstOrigin.toExponential(2)} m of the CSV's grasp origins`);
  check(worstDir < 1e-4, `their directions within ${worstDir.toExponential(2)} of the CSV's Wint_walker force`);
  check(worstLen < 5e-3, `their lengths within ${(100 * worstLen).toFixed(3)} % of |force| / (the legend's N per m)`);
  const movedM = Math.hypot(seen[1][2] - seen[0][2], seen[1][3] - seen[0][3], seen[1][4] - seen[0][4]);
  const movedPx = Math.hypot(seen[1][0] - seen[0][0], seen[1][1] - seen[0][1]);
  check(movedM > 0.05, `the load moves ${movedM.toFixed(3)} m in the CSV from t = 0 to the end`);
  check(worst < 1e-4, `the drawn box's corners within ${worst.toExponential(2)} m of the inertia box (edges ${edge.map((e) => e.toFixed(4)).join(' × ')} m) posed by the CSV`);
  check(movedPx > 20 && worstPx < 3, `the box's pixel centroid follows the CSV position (moved ${movedPx.toFixed(1)} px, within ${worstPx.toFixed(2)} px)`);
  await page.close();
}

// ---- the browser: Debian's chromium, no network
// (a fresh profile folder: launchPersistentContext passes it as --user-data-dir)
const context = await chromium.launchPersistentContext(fs.mkdtempSync(path.join(scratch, 'chromium-')), {
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  headless: true,
  args: ['--headless', '--no-sandbox', '--enable-unsafe-swiftshader', '--use-gl=angle', '--use-angle=swiftshader',
    '--disable-background-networking', '--disable-component-update', '--disable-sync', '--no-first-run'],
  viewport: { width: 1200, height: 800 },
  deviceScaleFactor: 1,
  offline: true,
});
try {
  const page = await context.newPage();
  const url = pathToFileURL(file).href;
  const refused = [], errors = [];
  await page.route('**/*', (route) => (route.request().url() === url ? route.continue() : (refused.push(route.request().url()), route.abort())));
  page.on('console', (m) => {
    if (m.type() === 'error') errors.push(`${m.type()}: ${m.text()}`);
    else if (m.type() === 'warning') console.log(`(console warning: ${m.text()})`);
  });
  page.on('pageerror', (e) => errors.push(`page error: ${e.message}`));
  page.on('requestfailed', (r) => { if (r.url() !== url) refused.push(r.url()); });
  await page.goto(url);
  await page.waitForFunction(() => window.ukdyn && window.ukdyn.ready, null, { timeout: 20000 });
  const canvas = page.locator('#view canvas');
  const shot = async () => decodePng(await canvas.screenshot());

  // the canvas is not blank: many pixels off the white background, in several colours
  await page.evaluate(() => window.ukdyn.setFrame(150));
  const a = await shot();
  let drawn = 0;
  const colours = new Set();
  for (let i = 0; i < a.w * a.h; i++) {
    const [r, g, b] = [a.px[4 * i], a.px[4 * i + 1], a.px[4 * i + 2]];
    if (r < 245 || g < 245 || b < 245) drawn++;
    colours.add((r >> 4) << 8 | (g >> 4) << 4 | (b >> 4));
  }
  check(drawn > 0.01 * a.w * a.h && colours.size > 20, `canvas drawn (${drawn} of ${a.w * a.h} pixels off white, ${colours.size} colours)`);

  // the same frame twice, with another in between: identical pixels
  await page.evaluate(() => window.ukdyn.setFrame(380));
  await page.evaluate(() => window.ukdyn.setFrame(150));
  const b = await shot();
  check(a.w === b.w && a.h === b.h && a.px.equals(b.px), 'two screenshots of frame 150 identical');

  // the marker at left.cut follows the simulated cut point
  const frames = await page.evaluate(() => window.ukdyn.frames);
  check(frames === rows.length, `the page has every sample (${frames} frames)`);
  check((await page.evaluate(() => window.ukdyn.markerOnly('left.cut', 0.03))) >= 0, 'marker at left.cut');
  let worst = 0;
  const seen = [];
  for (const i of [0, 50, 100, 200, 300, 400]) {
    const tPage = await page.evaluate((k) => (window.ukdyn.setFrame(k), window.ukdyn.data.t[k]), i);
    if (Math.abs(tPage - col('t')[i]) > 1e-6) fail(`frame ${i}: page t ${tPage} vs CSV ${col('t')[i]}`);
    const s = await shot();
    let n = 0, sx = 0, sy = 0;
    for (let y = 0; y < s.h; y++) for (let x = 0; x < s.w; x++) {
      const k = 4 * (y * s.w + x);
      // red, weighted by coverage (antialiased edges count in part)
      const wgt = s.px[k] / 255;
      if (s.px[k + 1] > 40 || s.px[k + 2] > 40 || wgt < 0.05) continue;
      n += wgt; sx += wgt * (x + 0.5); sy += wgt * (y + 0.5);
    }
    if (n < 10) fail(`frame ${i}: marker not visible (${n} px)`);
    const expect = await page.evaluate((p) => window.ukdyn.project(p), cut(i));
    const err = Math.hypot(sx / n - expect[0], sy / n - expect[1]);
    worst = Math.max(worst, err);
    seen.push([sx / n, sy / n]);
    console.log(`frame ${i} t=${tPage}: centroid (${(sx / n).toFixed(2)}, ${(sy / n).toFixed(2)}) px, projected (${expect[0].toFixed(2)}, ${expect[1].toFixed(2)}), ${n.toFixed(0)} px, error ${err.toFixed(3)} px`);
  }
  const moved = Math.hypot(seen[2][0] - seen[0][0], seen[2][1] - seen[0][1]);
  check(moved > 30, `the marker moved ${moved.toFixed(1)} px from t = 0 to 1 s`);
  check(worst < 0.5, `centroid within ${worst.toFixed(3)} px of the projected simulated cut point`);
  await page.close();
  await checkFreeBody(context, refused, errors);
  check(refused.length === 0, `no request but the file itself (${refused.length} refused: ${refused.slice(0, 3).join(' ')})`);
  check(errors.length === 0, `no console error (${errors.slice(0, 3).join(' | ')})`);
} finally {
  await context.close();
}
console.log(`passed in ${((Date.now() - started) / 1000).toFixed(1)} s`);
