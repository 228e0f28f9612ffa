// A rotatable 3-D view of a sample cloud (three.js): drag to turn, wheel
// to zoom. Drawing only: the points come from the core.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const COLOURS = {
  used: 0x2a6fdb,
  rejected: 0xd8342c,
  screened: 0xf08c00,
  dwell: 0x2ca02c,
  dropped: 0x999999,
  raw: 0x2a6fdb,
};

export class Cloud {
  constructor(element, { sphere }) {
    this.element = element;
    try {
      this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    } catch (err) {
      element.textContent = `The 3-D view needs WebGL (${err.message}).`;
      element.classList.add('no-webgl');
      return;
    }
    this.renderer.setPixelRatio(window.devicePixelRatio);
    element.append(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0xffffff);
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
    this.camera.position.set(2.6, 1.9, 2.4);
    this.camera.up.set(0, 0, 1);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener('change', () => this.render());
    this.scene.add(new THREE.AxesHelper(1.25));
    if (sphere) {
      const wire = new THREE.LineSegments(
        new THREE.WireframeGeometry(new THREE.SphereGeometry(1, 24, 12)),
        new THREE.LineBasicMaterial({ color: 0xc8ccd4 }),
      );
      wire.rotation.x = Math.PI / 2;
      this.scene.add(wire);
    }
    this.geometry = new THREE.BufferGeometry();
    this.material = new THREE.PointsMaterial({ size: 3, sizeAttenuation: false, vertexColors: true });
    this.scene.add(new THREE.Points(this.geometry, this.material));
    new ResizeObserver(() => this.resize()).observe(element);
    this.resize();
  }

  resize() {
    if (!this.renderer) return;
    const { clientWidth: w, clientHeight: h } = this.element;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / Math.max(h, 1);
    this.camera.updateProjectionMatrix();
    this.render();
  }

  // points: [[x, y, z], ...] (null values skipped); classes: one name per
  // point, or null; centre and radius: what is drawn at the origin and at
  // 1 (a fit's b and field strength). Without them the cloud is centred on
  // its midrange and scaled by the median of its points' distances, so
  // that a few wild readings do not shrink the rest to a dot; points far
  // off the scale leave the view.
  setPoints(points, classes, centre, radius) {
    if (!this.renderer) return;
    const finite = points.filter((p) => p && p.every(Number.isFinite));
    const c =
      centre ??
      [0, 1, 2].map((k) => {
        const v = finite.map((p) => p[k]).sort((a, b) => a - b);
        return v.length ? (v[Math.floor(v.length * 0.05)] + v[Math.floor(v.length * 0.95)]) / 2 : 0;
      });
    let r = radius;
    if (!r) {
      const d = finite.map((p) => Math.hypot(p[0] - c[0], p[1] - c[1], p[2] - c[2])).sort((a, b) => a - b);
      r = d.length ? d[Math.floor(d.length / 2)] || 1 : 1;
    }
    const scale = 1 / r;
    const position = [];
    const colour = [];
    const col = new THREE.Color();
    points.forEach((p, i) => {
      if (!p || !p.every(Number.isFinite)) return;
      position.push((p[0] - c[0]) * scale, (p[1] - c[1]) * scale, (p[2] - c[2]) * scale);
      col.setHex(COLOURS[classes ? classes[i].split(':')[0] : 'raw'] ?? COLOURS.raw);
      colour.push(col.r, col.g, col.b);
    });
    // The points drawn (read by the browser tests).
    this.count = position.length / 3;
    this.geometry.setAttribute('position', new THREE.Float32BufferAttribute(position, 3));
    this.geometry.setAttribute('color', new THREE.Float32BufferAttribute(colour, 3));
    this.geometry.computeBoundingSphere();
    this.render();
  }

  render() {
    if (this.renderer) this.renderer.render(this.scene, this.camera);
  }
}
