// ukdyn replay page (docs/replay.md). Data: the JSON block #ukdyn-data written by `ukdyn replay`:
//   t[frames], points[{name, kind}], segments[[a, b, kind]], pos[frames][3·points] (world, z up),
//   solids[{name, shape: box|sphere|ellipsoid|cylinder|capsule, size: [extents along its own axes;
//   cylinders and capsules along z], point: its centre, kind: load|link}], rot[frames][4·solids]
//   (w, x, y, z),
//   columns{name: values[frames]} (pose_<c>_* and Wint_walker_<c>_* pose the internal-force arrows), groups{title: [column names]}.
// Test hook: window.ukdyn (setFrame, setTime, markerOnly, solidOnly, solid, frames3d, squeeze, project, ready).
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const D = JSON.parse(document.getElementById('ukdyn-data').textContent);
const frames = D.t.length;
const np = D.points.length;
const solids = D.solids ?? [];
const $ = (id) => document.getElementById(id);
let frame = 0, playing = false, dirty = true, tPlay = D.t[0], last = null;
const plots = [];

$('name').textContent = D.name;
$('info').textContent = `${D.scenario} · t ∈ [${D.t[0]}, ${D.t[frames - 1]}] s · ${frames} frames` +
  (D.stride > 1 ? ` (1 in ${D.stride} of ${D.source_rows} samples)` : '') + ` · status ${D.status}`;
{  // what is not drawn, and the meshes drawn as their bounding boxes ("(mesh M: drawn as its bounding box)")
  const boxed = (D.left_out ?? []).filter((s) => s.endsWith(': drawn as its bounding box)'));
  const missing = (D.left_out ?? []).filter((s) => !boxed.includes(s));
  $('note').textContent = [missing.length ? `not drawn: ${missing.join(', ')}` : '',
    boxed.length ? `as bounding boxes: ${boxed.join(', ')}` : ''].filter((s) => s).join(' · ');
}

// ---- scene (world frame of the simulation: z up)
const view = $('view');
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
const background = new THREE.Color(0xffffff);
scene.background = background;
const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 1000);
camera.up.set(0, 0, 1);
const controls = new OrbitControls(camera, renderer.domElement);
controls.addEventListener('change', () => { dirty = true; });
const world = new THREE.Group();
scene.add(world);
world.add(new THREE.HemisphereLight(0xffffff, 0x8090a0, 2.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.2);
sun.position.set(3, -4, 6);
world.add(sun);

// Bounding box of every point over the run: sizes and the initial view.
const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
for (const p of D.pos) for (let i = 0; i < p.length; i++) {
  const v = p[i];
  if (v === null || !isFinite(v)) continue;
  lo[i % 3] = Math.min(lo[i % 3], v); hi[i % 3] = Math.max(hi[i % 3], v);
}
if (!isFinite(lo[0])) { lo.fill(-1); hi.fill(1); }
const extent = Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 0.5);
const centre = new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
const r = extent * 0.012 + 0.01;  // joint sphere radius

const grid = new THREE.GridHelper(Math.ceil(extent * 2 + 2), Math.ceil(extent * 2 + 2), 0x90a4ae, 0xcfd8dc);
grid.rotation.x = Math.PI / 2;
grid.position.set(Math.round(centre.x), Math.round(centre.y), Math.min(0, lo[2]) - 0.001);
world.add(grid);
world.add(new THREE.AxesHelper(extent * 0.15));

const colours = { platform: 0x546e7a, joint: 0x37474f, cut: 0xd32f2f, grasp: 0x2e7d32, com: 0x8e24aa, point: 0x1565c0 };
const segColours = { link: 0x78909c, load: 0xef6c00, base: 0x455a64 };
const sphere = new THREE.SphereGeometry(1, 20, 14);
const cylinder = new THREE.CylinderGeometry(1, 1, 1, 16);
const box = new THREE.BoxGeometry(1, 1, 1);
const pointMeshes = D.points.map((p) => {
  let m;
  if (p.kind === 'shape') {  // a solid's centre: the solid is drawn
    m = new THREE.Object3D();
  } else if (p.kind === 'platform') {
    m = new THREE.Mesh(box, new THREE.MeshStandardMaterial({ color: colours.platform }));
    m.scale.set(extent * 0.25, extent * 0.17, extent * 0.04);
  } else {
    m = new THREE.Mesh(sphere, new THREE.MeshStandardMaterial({ color: colours[p.kind] ?? colours.point }));
    const s = p.kind === 'cut' || p.kind === 'grasp' ? 1.6 : p.kind === 'com' ? 0.8 : 1.2;
    m.scale.setScalar(r * s);
  }
  world.add(m);
  return m;
});
const segMeshes = D.segments.map(([a, b, kind]) => {
  const m = new THREE.Mesh(cylinder, new THREE.MeshStandardMaterial({ color: segColours[kind] ?? segColours.link }));
  m.userData = { a, b, radius: kind === 'load' ? r * 1.3 : r * 0.7 };
  world.add(m);
  return m;
});
// Solids (a free body's inertia-equivalent box or its shape; a robot file's shapes on its links),
// posed by their centre point and D.rot. The geometry of each is built at unit size and scaled to
// the solid's extents (a capsule, whose caps do not scale, at its size); cylinders and capsules
// turned from three.js's y axis to the solid's z.
const unitSphere = new THREE.SphereGeometry(0.5, 24, 16);
const unitCylinder = new THREE.CylinderGeometry(0.5, 0.5, 1, 24).rotateX(Math.PI / 2);
function solidGeometry(s) {
  if (s.shape === 'sphere' || s.shape === 'ellipsoid') return [unitSphere, s.size];
  if (s.shape === 'cylinder') return [unitCylinder, s.size];
  if (s.shape === 'capsule') {
    const rad = s.size[0] / 2;
    return [new THREE.CapsuleGeometry(rad, Math.max(s.size[2] - 2 * rad, 0), 8, 16).rotateX(Math.PI / 2), [1, 1, 1]];
  }
  return [box, s.size];
}
const solidMeshes = solids.map((s) => {
  const [geometry, scale] = solidGeometry(s);
  const colour = s.kind === 'link' ? segColours.link : segColours.load;
  const m = new THREE.Mesh(geometry, new THREE.MeshStandardMaterial({ color: colour }));
  m.scale.set(scale[0], scale[1], scale[2]);
  world.add(m);
  return m;
});
// Frame constraints' frames (the grasp frames of a weld): small axes (x red, y green, z blue) posed by
// the CSV's pose_<c>_x, _y, _z, _qw, _qx, _qy, _qz columns (docs/frame-constraints.md).
const poseKeys = ['x', 'y', 'z', 'qw', 'qx', 'qy', 'qz'];
const frameAxes = Object.keys(D.columns).filter((n) => /^pose_.+_x$/.test(n)).map((n) => n.slice(5, -2))
  .filter((c) => poseKeys.every((k) => `pose_${c}_${k}` in D.columns))
  .map((c) => {
    const m = new THREE.AxesHelper(extent * 0.08);
    m.userData = { name: c, cols: poseKeys.map((k) => D.columns[`pose_${c}_${k}`]) };
    world.add(m);
    return m;
  });
// The internal (squeeze) force of each grasp of a load held by several welds: an arrow at the grasp
// frame's origin (pose_<c>_x, _y, _z) along the CSV's Wint_walker_<c>_fx, _fy, _fz (Walker's
// internal part of the grasp wrench, docs/frame-constraints.md), its length the force times one
// scale for the whole run (the largest force over the run and the grasps drawn at 15 % of the
// model's extent; the legend gives the scale).
const squeezeKeys = ['x', 'y', 'z', 'fx', 'fy', 'fz'];
const squeezeCols = (c) => squeezeKeys.map((k) => D.columns[k.length === 1 ? `pose_${c}_${k}` : `Wint_walker_${c}_${k}`]);
const squeezeNames = Object.keys(D.columns).filter((n) => /^Wint_walker_.+_fx$/.test(n)).map((n) => n.slice(12, -3))
  .filter((c) => squeezeCols(c).every((v) => v !== undefined));
let squeezeMax = 0;
for (const c of squeezeNames) {
  const [, , , fx, fy, fz] = squeezeCols(c);
  for (let f = 0; f < frames; f++) {
    const n = Math.hypot(fx[f], fy[f], fz[f]);
    if (Number.isFinite(n)) squeezeMax = Math.max(squeezeMax, n);
  }
}
const squeezeScale = squeezeMax > 0 ? 0.15 * extent / squeezeMax : 0;  // metres per newton
const squeezeColour = 0x00897b;
const squeezeArrows = squeezeNames.map((c) => {
  const m = new THREE.ArrowHelper(new THREE.Vector3(1, 0, 0), new THREE.Vector3(), 1, squeezeColour);
  m.userData = { name: c, cols: squeezeCols(c), length: 0 };
  world.add(m);
  return m;
});
if (squeezeArrows.length) {
  $('squeezeToggle').hidden = false;
  $('squeeze').onchange = () => { for (const m of squeezeArrows) m.visible = $('squeeze').checked && m.userData.length > 0; dirty = true; };
}
{
  const kinds = [...new Set(D.points.map((p) => p.kind))].filter((k) => k !== 'shape');
  $('legend').innerHTML = kinds.map((k) => `<i style="background:#${(colours[k] ?? colours.point).toString(16).padStart(6, '0')}"></i>${k}`).join('') +
    (D.segments.some((s) => s[2] === 'load') || solids.some((s) => s.kind !== 'link') ? `<i style="background:#ef6c00"></i>load` : '') +
    (squeezeArrows.length ? `<i style="background:#${squeezeColour.toString(16).padStart(6, '0')}"></i>internal force (Walker), ` +
      `<span id="squeezeScale">${squeezeScale > 0 ? `1 m = ${(1 / squeezeScale).toPrecision(3)} N` : 'zero throughout'}</span>` : '');
}

// The test marker: one unlit sphere of pure red, shown alone (window.ukdyn.markerOnly).
const marker = new THREE.Mesh(sphere, new THREE.MeshBasicMaterial({ color: 0xff0000 }));
marker.visible = false;
scene.add(marker);
let markerPoint = -1;
// The same for one solid: its box alone, unlit pure red (window.ukdyn.solidOnly).
const solidMarker = new THREE.Mesh(box, new THREE.MeshBasicMaterial({ color: 0xff0000 }));
solidMarker.visible = false;
scene.add(solidMarker);
let markerSolid = -1;

// Path of a chosen point over the whole run.
let pathLine = null;
function setPath(i) {
  if (pathLine) { world.remove(pathLine); pathLine.geometry.dispose(); pathLine = null; }
  if (i >= 0) {
    const xyz = new Float32Array(frames * 3);
    for (let f = 0; f < frames; f++) for (let k = 0; k < 3; k++) xyz[3 * f + k] = D.pos[f][3 * i + k] ?? NaN;
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(xyz, 3));
    pathLine = new THREE.Line(g, new THREE.LineBasicMaterial({ color: 0xd81b60 }));
    world.add(pathLine);
  }
  dirty = true;
}

const up = new THREE.Vector3(0, 1, 0), va = new THREE.Vector3(), vb = new THREE.Vector3(), dir = new THREE.Vector3();
function pointAt(f, i, v) { const p = D.pos[f]; return v.set(p[3 * i] ?? NaN, p[3 * i + 1] ?? NaN, p[3 * i + 2] ?? NaN); }
function place(f) {
  for (let i = 0; i < np; i++) {
    pointAt(f, i, va);
    const m = pointMeshes[i];
    m.position.copy(va);
    if (D.points[i].kind === 'platform') m.position.z -= m.scale.z / 2;
  }
  for (const m of segMeshes) {
    pointAt(f, m.userData.a, va); pointAt(f, m.userData.b, vb);
    dir.subVectors(vb, va);
    const len = dir.length();
    m.visible = len > 1e-9 && markerPoint < 0;
    if (!m.visible) continue;
    m.position.addVectors(va, vb).multiplyScalar(0.5);
    m.quaternion.setFromUnitVectors(up, dir.divideScalar(len));
    m.scale.set(m.userData.radius, len, m.userData.radius);
  }
  solidMeshes.forEach((m, i) => {
    pointAt(f, solids[i].point, m.position);
    const q = D.rot[f];
    m.quaternion.set(q[4 * i + 1] ?? 0, q[4 * i + 2] ?? 0, q[4 * i + 3] ?? 0, q[4 * i] ?? 1);
  });
  for (const m of frameAxes) {
    const v = m.userData.cols.map((c) => c[f] ?? NaN);
    m.visible = v.every(Number.isFinite);
    if (m.visible) { m.position.set(v[0], v[1], v[2]); m.quaternion.set(v[4], v[5], v[6], v[3]).normalize(); }
  }
  for (const m of squeezeArrows) {
    const v = m.userData.cols.map((c) => c[f] ?? NaN);
    const n = Math.hypot(v[3], v[4], v[5]);
    m.userData.length = v.every(Number.isFinite) && n > 0 ? n * squeezeScale : 0;
    m.visible = m.userData.length > 0 && $('squeeze').checked;
    if (m.userData.length > 0) {
      m.position.set(v[0], v[1], v[2]);
      m.setDirection(va.set(v[3] / n, v[4] / n, v[5] / n));
      const len = m.userData.length;
      m.setLength(len, Math.min(0.2 * len, extent * 0.03), Math.min(0.1 * len, extent * 0.015));
    }
  }
  if (markerPoint >= 0) { pointAt(f, markerPoint, va); marker.position.copy(va); }
  if (markerSolid >= 0) {
    const m = solidMeshes[markerSolid];
    solidMarker.position.copy(m.position); solidMarker.quaternion.copy(m.quaternion); solidMarker.scale.copy(m.scale);
  }
}

// ---- camera: looking at the centre from the front-left, above
camera.position.set(centre.x - extent * 1.1, centre.y - extent * 1.6, centre.z + extent * 0.9);
controls.target.copy(centre);
controls.update();

function resize() {
  const w = view.clientWidth, h = view.clientHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(h, 1);
  camera.updateProjectionMatrix();
  dirty = true;
  for (const p of plots) p.resize();
}
window.addEventListener('resize', resize);

// ---- plots of CSV columns, with a cursor at the current time
const palette = ['#1565c0', '#c62828', '#2e7d32', '#ef6c00', '#6a1b9a', '#00838f', '#5d4037', '#ad1457', '#9e9d24', '#283593', '#4e342e', '#00695c'];
function addPlot(title, names) {
  names = names.filter((n) => n in D.columns);
  if (!names.length) return;
  const div = document.createElement('div');
  div.className = 'plot';
  div.innerHTML = `<div class="title"><span></span><button title="remove">✕</button></div><canvas></canvas>`;
  div.querySelector('span').textContent = title;
  $('plots').appendChild(div);
  const canvas = div.querySelector('canvas');
  let ymin = Infinity, ymax = -Infinity;
  for (const n of names) for (const v of D.columns[n]) if (v !== null && isFinite(v)) { ymin = Math.min(ymin, v); ymax = Math.max(ymax, v); }
  if (!isFinite(ymin)) { ymin = -1; ymax = 1; }
  if (ymax - ymin < 1e-300) { ymin -= 1; ymax += 1; }
  const plot = {
    resize() { canvas.width = canvas.clientWidth; canvas.height = canvas.clientHeight; this.base = null; this.draw(); },
    draw() {
      const ctx = canvas.getContext('2d', { willReadFrequently: true });
      const W = canvas.width, H = canvas.height, L = 62, R = 8, T = 6, B = 18;
      const x = (t) => L + (t - D.t[0]) / Math.max(D.t[frames - 1] - D.t[0], 1e-300) * (W - L - R);
      const y = (v) => T + (ymax - v) / (ymax - ymin) * (H - T - B);
      if (!this.base) {
        ctx.fillStyle = '#fff'; ctx.fillRect(0, 0, W, H);
        ctx.strokeStyle = '#ccc'; ctx.strokeRect(L, T, W - L - R, H - T - B);
        ctx.fillStyle = '#555'; ctx.font = '11px sans-serif';
        ctx.fillText(ymax.toPrecision(3), 2, T + 9); ctx.fillText(ymin.toPrecision(3), 2, H - B);
        ctx.fillText(`${D.t[0]} s`, L, H - 4); ctx.textAlign = 'right'; ctx.fillText(`${D.t[frames - 1]} s`, W - R, H - 4); ctx.textAlign = 'left';
        names.forEach((n, k) => {
          ctx.strokeStyle = palette[k % palette.length]; ctx.lineWidth = 1.3; ctx.beginPath();
          let pen = false;
          const v = D.columns[n];
          for (let f = 0; f < frames; f++) {
            if (v[f] === null || !isFinite(v[f])) { pen = false; continue; }
            if (pen) ctx.lineTo(x(D.t[f]), y(v[f])); else ctx.moveTo(x(D.t[f]), y(v[f]));
            pen = true;
          }
          ctx.stroke();
          ctx.fillStyle = palette[k % palette.length];
          if (k < 8) ctx.fillText(n, L + 4 + (k % 4) * ((W - L) / 4), T + 12 + Math.floor(k / 4) * 12);
        });
        this.base = ctx.getImageData(0, 0, W, H);
      } else {
        ctx.putImageData(this.base, 0, 0);
      }
      ctx.strokeStyle = '#000'; ctx.lineWidth = 1; ctx.beginPath();
      const cx = Math.round(x(D.t[frame])) + 0.5;
      ctx.moveTo(cx, T); ctx.lineTo(cx, H - B); ctx.stroke();
    },
  };
  div.querySelector('button').onclick = () => { div.remove(); plots.splice(plots.indexOf(plot), 1); };
  plots.push(plot);
  plot.resize();
}

// ---- playback
const slider = $('slider');
slider.max = String(frames - 1);
function setFrame(f) {
  frame = Math.max(0, Math.min(frames - 1, f | 0));
  slider.value = String(frame);
  $('time').textContent = `t = ${D.t[frame].toFixed(3)} s`;
  place(frame);
  for (const p of plots) p.draw();
  dirty = true;
}
function frameAt(t) {  // the last frame at or before t
  let a = 0, b = frames - 1;
  if (t >= D.t[b]) return b;
  while (b - a > 1) { const m = (a + b) >> 1; if (D.t[m] <= t) a = m; else b = m; }
  return a;
}
function setPlaying(on) {
  playing = on; last = null;
  $('play').textContent = on ? '❚❚ pause' : '▶ play';
  if (on && frame === frames - 1) tPlay = D.t[0]; else tPlay = D.t[frame];
}
$('play').onclick = () => setPlaying(!playing);
window.addEventListener('keydown', (e) => { if (e.code === 'Space' && e.target.tagName !== 'SELECT') { e.preventDefault(); setPlaying(!playing); } });
slider.oninput = () => { setPlaying(false); setFrame(+slider.value); };
D.points.forEach((p, i) => { const o = document.createElement('option'); o.value = String(i); o.textContent = p.name; $('path').appendChild(o); });
$('path').onchange = () => setPath(+$('path').value);
for (const n of Object.keys(D.columns)) { const o = document.createElement('option'); o.textContent = n; $('addplot').appendChild(o); }
$('addplot').onchange = () => { const n = $('addplot').value; if (n) addPlot(n, [n]); $('addplot').value = ''; };
for (const [title, names] of Object.entries(D.groups)) addPlot(title, names);
const cutIndex = D.points.findIndex((p) => p.kind === 'cut');
if (cutIndex >= 0) { $('path').value = String(cutIndex); setPath(cutIndex); }

function loop(now) {
  if (playing) {
    if (last !== null) tPlay += (now - last) / 1000 * +$('speed').value;
    last = now;
    if (tPlay >= D.t[frames - 1]) { tPlay = D.t[frames - 1]; setFrame(frames - 1); setPlaying(false); }
    else if (frameAt(tPlay) !== frame) setFrame(frameAt(tPlay));
  }
  if (dirty) { renderer.render(scene, camera); dirty = false; }
  requestAnimationFrame(loop);
}
resize();
setFrame(0);
requestAnimationFrame(loop);

// ---- test hook (tests/browser/replay_test.mjs)
window.ukdyn = {
  data: D,
  frames,
  setFrame(f) { setPlaying(false); setFrame(f); renderer.render(scene, camera); dirty = false; return frame; },
  setTime(t) { return this.setFrame(frameAt(t)); },
  /// Shows only a red unlit sphere at point `name` on a black background (or everything again
  /// with null); the marker's radius in metres.
  markerOnly(name, radius = 0.03) {
    markerPoint = name === null ? -1 : D.points.findIndex((p) => p.name === name);
    world.visible = markerPoint < 0;
    $('legend').style.display = markerPoint < 0 ? '' : 'none';  // (it lies over the canvas)
    marker.visible = markerPoint >= 0;
    marker.scale.setScalar(radius);
    scene.background = markerPoint >= 0 ? new THREE.Color(0x000000) : background;
    place(frame);
    renderer.render(scene, camera);
    return markerPoint;
  },
  /// Shows only solid `name` as an unlit red box on black (or everything again with null).
  solidOnly(name) {
    markerSolid = name === null ? -1 : solids.findIndex((s) => s.name === name);
    world.visible = markerSolid < 0;
    $('legend').style.display = markerSolid < 0 ? '' : 'none';
    solidMarker.visible = markerSolid >= 0;
    if (markerSolid >= 0) solidMarker.geometry = solidMeshes[markerSolid].geometry;
    scene.background = markerSolid >= 0 ? new THREE.Color(0x000000) : background;
    place(frame);
    renderer.render(scene, camera);
    return markerSolid;
  },
  /// Solid `name` as drawn at the current frame: its shape, position, quaternion [w, x, y, z] and
  /// the world positions of the 8 corners of its box of extents (null if there is no such solid).
  solid(name) {
    const i = solids.findIndex((s) => s.name === name);
    if (i < 0) return null;
    const m = solidMeshes[i], e = solids[i].size;
    const corners = [];
    for (const x of [-0.5, 0.5]) for (const y of [-0.5, 0.5]) for (const z of [-0.5, 0.5]) {
      const v = new THREE.Vector3(x * e[0], y * e[1], z * e[2]).applyQuaternion(m.quaternion).add(m.position);
      corners.push([v.x, v.y, v.z]);
    }
    return { shape: solids[i].shape, position: m.position.toArray(), quaternion: [m.quaternion.w, m.quaternion.x, m.quaternion.y, m.quaternion.z], corners };
  },
  /// The frame constraints drawn as axes: [{name, position, quaternion [w, x, y, z]}] at this frame.
  frames3d() {
    return frameAxes.map((m) => ({ name: m.userData.name, position: m.position.toArray(), quaternion: [m.quaternion.w, m.quaternion.x, m.quaternion.y, m.quaternion.z] }));
  },
  /// The internal-force arrows as drawn at this frame: [{name, origin, direction (unit), length
  /// (m), visible}], and the scale in metres per newton.
  squeeze() {
    return {
      scale: squeezeScale,
      arrows: squeezeArrows.map((m) => {
        const d = new THREE.Vector3(0, 1, 0).applyQuaternion(m.quaternion);
        return { name: m.userData.name, origin: m.position.toArray(), direction: d.toArray(), length: m.userData.length, visible: m.visible };
      }),
    };
  },
  /// The canvas pixel (x right, y down, CSS pixels from the canvas' top-left) of world point xyz
  /// through the page's camera.
  project(xyz) {
    const v = new THREE.Vector3(xyz[0], xyz[1], xyz[2]).project(camera);
    return [(v.x + 1) / 2 * renderer.domElement.clientWidth, (1 - v.y) / 2 * renderer.domElement.clientHeight];
  },
  ready: true,
};
