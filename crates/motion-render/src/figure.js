// Shared by viewer.js and play.js (embedded before each, after three.js):
// the lit scene, and stick figures drawn from global joint positions.
const MotionFigure = (function () {
  'use strict';
  const LEFT = new Set([1, 2, 3, 4, 13, 14, 15]), RIGHT = new Set([5, 6, 7, 8, 16, 17, 18]);
  const mat = (c) => new THREE.MeshStandardMaterial({ color: c, roughness: 0.6 });
  const colours = { left: mat(0x285ac8), right: mat(0xc83228), centre: mat(0x3c3c3c), other: mat(0xe08a1e) };
  const boneGeo = new THREE.CylinderGeometry(0.45, 0.45, 1, 10);
  const headGeo = new THREE.SphereGeometry(1.4, 16, 12);
  const UP = new THREE.Vector3(0, 1, 0);
  const a = new THREE.Vector3(), b = new THREE.Vector3(), dir = new THREE.Vector3();
  // A light grey scene lit from the sky and the sun.
  function scene() {
    const s = new THREE.Scene();
    s.background = new THREE.Color(0xf7f7f7);
    s.add(new THREE.HemisphereLight(0xffffff, 0x8a8a8a, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(40, 80, 60);
    s.add(sun);
    return s;
  }
  // A figure in `group`: left limbs blue, right red (all orange if `other`).
  function make(parents, group, other) {
    const bones = parents.map((p, j) => {
      if (p < 0) return null;
      const c = other ? colours.other : LEFT.has(j) ? colours.left : RIGHT.has(j) ? colours.right : colours.centre;
      const m = new THREE.Mesh(boneGeo, c);
      group.add(m);
      return m;
    });
    const head = new THREE.Mesh(headGeo, other ? colours.other : colours.centre);
    group.add(head);
    return { bones, head, parents };
  }
  // Places the figure's bones between the joints of `f` ([x, y, z] each).
  function pose(fig, f) {
    fig.parents.forEach((p, j) => {
      if (p < 0) return;
      a.fromArray(f[p]); b.fromArray(f[j]);
      dir.subVectors(b, a);
      const len = dir.length(), bone = fig.bones[j];
      bone.position.addVectors(a, b).multiplyScalar(0.5);
      bone.scale.set(1, Math.max(len, 1e-3), 1);
      if (len > 1e-9) bone.quaternion.setFromUnitVectors(UP, dir.divideScalar(len));
    });
    fig.head.position.fromArray(f[12]);
  }
  return { scene, make, pose, mat };
})();
