// The motion viewer (motion-render/src/viewer.rs embeds this file in
// viewer.html after the three.js bundle, which defines the global THREE).
// Data: <script id="motion-data"> = [{name, group, data: {fps, joints,
// parents, motions: [{id, frames: [[[x, y, z] x joints] x frames]}]}}].
// Query: ?frame=N opens paused at frame N; ?set=K picks a set; ?overlay=1
// overlays the motions of a group (a real window and its reconstruction).
(function () {
  'use strict';
  const status = (s) => { document.body.dataset.status = s; };
  window.addEventListener('error', (e) => {
    status('error: ' + e.message);
    document.getElementById('err').textContent = 'JavaScript error: ' + e.message;
  });
  const sets = JSON.parse(document.getElementById('motion-data').textContent);
  const q = new URLSearchParams(location.search);
  const $ = (id) => document.getElementById(id);
  const sel = $('set'), play = $('play'), slider = $('slider'), label = $('label');
  const speedSel = $('speed'), overlayBox = $('overlay'), view = $('view');
  sets.forEach((s, i) => {
    const o = document.createElement('option');
    o.value = i; o.textContent = s.name + ' (' + s.data.motions.length + ')';
    sel.appendChild(o);
  });
  if (q.has('set')) sel.value = String(Math.min(+q.get('set') || 0, sets.length - 1));
  overlayBox.checked = q.get('overlay') === '1';

  let renderer;
  try {
    renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  } catch (e) {
    status('error: WebGL unavailable');
    $('err').textContent = 'This viewer needs WebGL: ' + e.message;
    return;
  }
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  view.appendChild(renderer.domElement);
  const scene = MotionFigure.scene();
  const camera = new THREE.PerspectiveCamera(40, 1, 0.5, 5000);
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.enableDamping = false;
  controls.addEventListener('change', () => render());

  const traceMat = [new THREE.LineBasicMaterial({ color: 0x555555 }), new THREE.LineBasicMaterial({ color: 0xe08a1e })];
  let world = null, figures = [], frame = 0, playing = true, last = 0, acc = 0;

  function current() { return sets[+sel.value]; }
  function frames() { return Math.max(1, ...current().data.motions.map((m) => m.frames.length)); }

  // Build the scene for the current set: one figure per motion, placed in
  // a grid (or overlaid per group), each with its root trace on the floor.
  function build() {
    if (world) scene.remove(world);
    world = new THREE.Group();
    scene.add(world);
    figures = [];
    const set = current(), d = set.data, ms = d.motions;
    const group = overlayBox.checked ? Math.max(1, set.group || 1) : 1;
    const cells = Math.ceil(ms.length / group), cols = Math.ceil(Math.sqrt(cells));
    // Cell size from the 75th percentile of how far a root travels, so one
    // runaway motion does not shrink all the others.
    const travel = ms.map((m) => Math.max(0, ...m.frames.map((f) =>
      Math.hypot(f[0][0] - m.frames[0][0][0], f[0][2] - m.frames[0][0][2])))).sort((x, y) => x - y);
    const p75 = travel[Math.floor(0.75 * (travel.length - 1))] || 0;
    const spacing = Math.min(90, Math.max(40, 2 * p75 + 20));
    ms.forEach((m, k) => {
      const cell = Math.floor(k / group), member = k % group;
      const off = new THREE.Vector3((cell % cols) * spacing, 0, Math.floor(cell / cols) * spacing);
      off.x -= m.frames[0][0][0]; off.z -= m.frames[0][0][2];
      const g = new THREE.Group();
      g.position.copy(off);
      const fig = MotionFigure.make(d.parents, g, member > 0);
      const pts = [];
      m.frames.forEach((f) => pts.push(f[0][0], 0.05, f[0][2]));
      const tg = new THREE.BufferGeometry();
      tg.setAttribute('position', new THREE.Float32BufferAttribute(pts, 3));
      g.add(new THREE.Line(tg, traceMat[member > 0 ? 1 : 0]));
      world.add(g);
      figures.push({ m, fig });
    });
    const w = cols * spacing, h = Math.ceil(cells / cols) * spacing;
    const grid = new THREE.GridHelper(Math.ceil((Math.max(w, h) + spacing) / 10) * 10, Math.ceil((Math.max(w, h) + spacing) / 10), 0xb0b0b0, 0xd8d8d8);
    grid.position.set((cols - 1) * spacing / 2, 0, (Math.ceil(cells / cols) - 1) * spacing / 2);
    world.add(grid);
    const centre = new THREE.Vector3(grid.position.x, 14, grid.position.z);
    const dist = Math.max(95, 1.1 * Math.max(w, h));
    camera.position.set(centre.x + dist * 0.55, centre.y + dist * 0.45, centre.z + dist * 0.8);
    controls.target.copy(centre);
    controls.update();
    slider.max = frames() - 1;
    $('legend').textContent = group > 1
      ? 'Overlaid: ' + ms.filter((_, k) => k % group === 0).map((m) => m.id).join(', ') + ' (blue/red) with ' + ms.filter((_, k) => k % group > 0).map((m) => m.id).join(', ') + ' (orange).'
      : 'Left limbs blue, right limbs red; grey line: the root\u2019s path on the floor.';
  }

  function pose() {
    figures.forEach(({ m, fig }) => MotionFigure.pose(fig, m.frames[Math.min(frame, m.frames.length - 1)]));
    slider.value = frame;
    const fps = current().data.fps;
    label.textContent = 'frame ' + frame + ' / ' + (frames() - 1) + ' (' + (frame / fps).toFixed(2) + ' s)';
  }
  function resize() {
    const w = Math.max(320, window.innerWidth - 24), h = Math.max(240, window.innerHeight - 110);
    renderer.setSize(w, h);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
  }
  function render() { renderer.render(scene, camera); }
  function tick(ts) {
    const dt = Math.min(0.25, (ts - (last || ts)) / 1000);
    last = ts;
    if (playing) {
      acc += dt * current().data.fps * +speedSel.value;
      if (acc >= 1) { frame = (frame + Math.floor(acc)) % frames(); acc -= Math.floor(acc); pose(); render(); }
    }
    requestAnimationFrame(tick);
  }
  function setPlaying(p) { playing = p; play.textContent = p ? 'pause' : 'play'; }
  sel.onchange = () => { frame = 0; build(); pose(); render(); };
  overlayBox.onchange = sel.onchange;
  play.onclick = () => setPlaying(!playing);
  slider.oninput = () => { frame = +slider.value; setPlaying(false); pose(); render(); };
  window.addEventListener('resize', () => { resize(); render(); });
  if (q.has('frame')) { frame = Math.max(0, +q.get('frame') || 0); setPlaying(false); }
  resize();
  build();
  frame = Math.min(frame, frames() - 1);
  pose();
  render();
  status('ok');
  requestAnimationFrame(tick);
})();
