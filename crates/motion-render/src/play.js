// The live player (motion-render/src/play.rs embeds this file in play.html
// after the three.js bundle). The model runs in WebAssembly (motion-play,
// base64 in <script id="play-wasm">), its bundle beside it (<script
// id="play-bundle">); <script id="play-meta"> = {fps, parents, seed}.
// Keys: arrows or WASD turn and go, Shift runs, Space stops, digits pick a
// category, R starts again. window.play exposes the state to tests.
(function () {
  'use strict';
  const $ = (id) => document.getElementById(id);
  const play = window.play = { ready: false, errors: [], frames: 0, stepMs: 0, state: null };
  const status = (s) => { document.body.dataset.status = s; };
  const fail = (m) => { play.errors.push(m); status('error: ' + m); $('err').textContent = m; };
  window.addEventListener('error', (e) => fail('JavaScript error: ' + e.message));
  window.addEventListener('unhandledrejection', (e) => fail('JavaScript error: ' + e.reason));
  const meta = JSON.parse($('play-meta').textContent);
  const bytes = (id) => Uint8Array.from(atob($(id).textContent.trim()), (c) => c.charCodeAt(0));

  // The module's imports (the browser's random numbers, never called by the
  // player) are answered with functions that say so.
  const wasmModule = new WebAssembly.Module(bytes('play-wasm'));
  const imports = {};
  for (const i of WebAssembly.Module.imports(wasmModule)) {
    imports[i.module] = imports[i.module] || {};
    imports[i.module][i.name] = () => { throw new Error('the player called ' + i.module + '.' + i.name); };
  }
  const wasm = new WebAssembly.Instance(wasmModule, imports).exports;
  const text = () => new TextDecoder().decode(new Uint8Array(wasm.memory.buffer, wasm.play_text(), wasm.play_text_len()));
  const bundle = bytes('play-bundle');
  const ptr = wasm.play_alloc(bundle.length);
  new Uint8Array(wasm.memory.buffer, ptr, bundle.length).set(bundle);
  if (!wasm.play_new(ptr, bundle.length, meta.seed)) { fail(text()); return; }
  wasm.play_categories();
  const categories = text().split(',');
  const J = meta.parents.length, VALUES = 3 * J + 8;

  let renderer;
  try {
    renderer = new THREE.WebGLRenderer({ antialias: true });
  } catch (e) { fail('This page needs WebGL: ' + e.message); return; }
  $('view').appendChild(renderer.domElement);
  const scene = MotionFigure.scene();
  // A floor of 10-unit (0.56 m) squares that follows the figure.
  const grid = new THREE.GridHelper(400, 40, 0x909090, 0xc4c4c4);
  scene.add(grid);
  const camera = new THREE.PerspectiveCamera(40, 1, 0.5, 5000);
  const figure = MotionFigure.make(meta.parents, scene, false);
  const trace = [], traceGeo = new THREE.BufferGeometry();
  scene.add(new THREE.Line(traceGeo, new THREE.LineBasicMaterial({ color: 0x555555 })));
  // The asked heading and speed: an orange segment from the root, a ball at its end.
  const askedGeo = new THREE.BufferGeometry();
  scene.add(new THREE.Line(askedGeo, new THREE.LineBasicMaterial({ color: 0xe08a1e })));
  const askedEnd = new THREE.Mesh(new THREE.SphereGeometry(1.2, 12, 8), MotionFigure.mat(0xe08a1e));
  scene.add(askedEnd);

  const held = new Set();
  let stopPressed = false;
  const KEYS = ['ArrowLeft', 'ArrowRight', 'ArrowUp', 'ArrowDown', 'Space', 'KeyA', 'KeyD', 'KeyW', 'KeyS'];
  window.addEventListener('keydown', (e) => {
    if (KEYS.includes(e.code)) e.preventDefault();
    held.add(e.code);
    if (e.code === 'Space' || e.code === 'ArrowDown' || e.code === 'KeyS') stopPressed = true;
    const d = /^Digit([1-9])$/.exec(e.code);
    if (d && +d[1] <= categories.length && !wasm.play_pick(+d[1] - 1, 0)) fail(text());
    if (e.code === 'KeyR') { if (!wasm.play_pick(category(), 1)) fail(text()); trace.length = 0; }
  });
  window.addEventListener('keyup', (e) => held.delete(e.code));
  window.addEventListener('blur', () => held.clear());
  const any = (...c) => c.some((k) => held.has(k));
  const category = () => (play.state ? play.state.category : 0);

  // One frame of the model, with the keys held now.
  let f = null;
  function step() {
    const turn = (any('ArrowRight', 'KeyD') ? 1 : 0) - (any('ArrowLeft', 'KeyA') ? 1 : 0);
    const t0 = performance.now();
    const ok = wasm.play_step(turn, any('ArrowUp', 'KeyW') ? 1 : 0, any('ShiftLeft', 'ShiftRight') ? 1 : 0, stopPressed ? 1 : 0);
    const ms = performance.now() - t0;
    stopPressed = false;
    if (!ok) { fail(text()); return false; }
    f = new Float32Array(wasm.memory.buffer, wasm.play_frame(), VALUES).slice();
    play.frames += 1;
    play.stepMs += (ms - play.stepMs) / play.frames;
    const r = 3 * J;
    play.state = {
      frame: play.frames, root: [f[r], f[r + 1]], facing: [f[r + 2], f[r + 3]],
      heading: [f[r + 4], f[r + 5]], speed: f[r + 6], category: f[r + 7],
      hips: [f[0], f[1], f[2]], fps: 1000 / Math.max(play.stepMs, 1e-6),
    };
    trace.push(f[0], 0.05, f[2]);
    if (trace.length > 3 * 1800) trace.splice(0, 3);
    return true;
  }
  function draw() {
    if (!f) return;
    MotionFigure.pose(figure, Array.from({ length: J }, (_, j) => [f[3 * j], f[3 * j + 1], f[3 * j + 2]]));
    traceGeo.setAttribute('position', new THREE.Float32BufferAttribute(trace, 3));
    const s = play.state;
    const reach = 8 + 12 * s.speed;
    const end = [f[0] + reach * s.heading[0], 0.3, f[2] + reach * s.heading[1]];
    askedGeo.setAttribute('position', new THREE.Float32BufferAttribute([f[0], 0.3, f[2], ...end], 3));
    askedEnd.position.fromArray(end);
    grid.position.set(10 * Math.round(f[0] / 10), 0, 10 * Math.round(f[2] / 10));
    camera.position.set(f[0] + 60, 55, f[2] + 90);
    camera.lookAt(f[0], 14, f[2]);
    renderer.render(scene, camera);
    const deg = Math.atan2(s.heading[0], s.heading[1]) * 180 / Math.PI;
    $('hud').textContent = categories[s.category] + ' \u00b7 asked ' + (s.speed > 0 ? s.speed.toFixed(2) + ' m/s' : 'stand') +
      ' heading ' + deg.toFixed(0) + '\u00b0 \u00b7 ' + s.fps.toFixed(0) + ' frames/s possible';
  }
  function resize() {
    const w = Math.max(320, window.innerWidth - 24), h = Math.max(240, window.innerHeight - 110);
    renderer.setSize(w, h);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
  }
  window.addEventListener('resize', resize);
  resize();
  $('keys').textContent = 'Arrows or WASD: turn, go \u00b7 Shift: run \u00b7 Space: stop \u00b7 R: start again \u00b7 ' +
    categories.map((c, i) => (i + 1) + ': ' + c).join(', ');
  // Frames at meta.fps in real time, whatever the display's rate: a timer
  // steps the model (at most 4 frames to catch up), animation frames draw.
  let due = performance.now();
  setInterval(() => {
    const now = performance.now();
    for (let n = 0; now >= due && n < 4; n++, due += 1000 / meta.fps) if (!step()) return;
    if (now >= due) due = now;
  }, 1000 / meta.fps / 2);
  const frame = () => { draw(); requestAnimationFrame(frame); };
  requestAnimationFrame(frame);
  play.ready = true;
  status('ok');
})();
