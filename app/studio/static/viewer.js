// drawstring studio: the 3D view of a target surface (a triangle mesh), on the report's three.js.
// Drag to turn, shift- or right-drag to pan, wheel to zoom, double-click to fit.  Z is up; mm.

import * as THREE from "./three.module.min.js";

export class MeshView {
  constructor(host) {
    this.host = host;
    this.renders = 0;
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.setClearColor(0xf4f5f7);
    host.appendChild(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(35, 1, 0.1, 10000);
    this.camera.up.set(0, 0, 1);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8f99, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(1, -1.5, 2.5);
    this.scene.add(sun);
    this.mesh = null;
    this.orbit = { target: new THREE.Vector3(), radius: 1, theta: -Math.PI / 3, phi: 1.0 };
    this.pending = false;
    this._controls();
    new ResizeObserver(() => this.resize()).observe(host);
    this.resize();
  }

  // Show a preview ({vertices: [x, y, z, ...], faces: [a, b, c, ...]}), centred, fitted.
  show(preview) {
    if (this.mesh) {
      this.scene.remove(this.mesh);
      this.mesh.traverse((o) => { if (o.geometry) o.geometry.dispose(); });
    }
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.Float32BufferAttribute(preview.vertices, 3));
    geometry.setIndex(preview.faces);
    geometry.computeVertexNormals();
    geometry.computeBoundingSphere();
    const front = new THREE.MeshStandardMaterial({ color: 0xd9480f, roughness: 0.65, side: THREE.FrontSide, flatShading: false });
    const back = new THREE.MeshStandardMaterial({ color: 0x868e96, roughness: 0.8, side: THREE.BackSide });
    const group = new THREE.Group();
    group.add(new THREE.Mesh(geometry, front), new THREE.Mesh(geometry, back));
    const sphere = geometry.boundingSphere;
    group.position.copy(sphere.center).negate();
    this.mesh = group;
    this.scene.add(group);
    this.radius = sphere.radius || 1;
    this.fit();
    this.render();
  }

  clear() {
    if (this.mesh) this.scene.remove(this.mesh);
    this.mesh = null;
    this.render();
  }

  fit() {
    const cam = this.camera;
    const half = Math.min(cam.fov, (2 * Math.atan(Math.tan((cam.fov * Math.PI) / 360) * cam.aspect) * 180) / Math.PI) / 2;
    this.orbit.radius = ((this.radius || 1) / Math.sin((half * Math.PI) / 180)) * 0.9;
    this.orbit.target.set(0, 0, 0);
    cam.near = this.orbit.radius / 1000;
    cam.far = this.orbit.radius * 100;
    cam.updateProjectionMatrix();
  }

  render() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      const o = this.orbit;
      const s = Math.sin(o.phi);
      this.camera.position.set(s * Math.cos(o.theta), s * Math.sin(o.theta), Math.cos(o.phi)).multiplyScalar(o.radius).add(o.target);
      this.camera.lookAt(o.target);
      this.renderer.render(this.scene, this.camera);
      this.renders += 1;
    });
  }

  resize() {
    const w = this.host.clientWidth || 400;
    const h = this.host.clientHeight || 300;
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  _controls() {
    const el = this.renderer.domElement;
    let drag = null;
    el.addEventListener("contextmenu", (e) => e.preventDefault());
    el.addEventListener("pointerdown", (e) => {
      drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey || e.ctrlKey };
      el.setPointerCapture(e.pointerId);
    });
    el.addEventListener("pointermove", (e) => {
      if (!drag) return;
      const dx = e.clientX - drag.x;
      const dy = e.clientY - drag.y;
      drag.x = e.clientX;
      drag.y = e.clientY;
      const o = this.orbit;
      if (drag.pan) {
        const scale = (2 * o.radius * Math.tan((this.camera.fov * Math.PI) / 360)) / el.clientHeight;
        const right = new THREE.Vector3().setFromMatrixColumn(this.camera.matrix, 0);
        const up = new THREE.Vector3().setFromMatrixColumn(this.camera.matrix, 1);
        o.target.addScaledVector(right, -dx * scale).addScaledVector(up, dy * scale);
      } else {
        o.theta -= dx * 0.008;
        o.phi = Math.min(Math.PI - 0.01, Math.max(0.01, o.phi - dy * 0.008));
      }
      this.render();
    });
    el.addEventListener("pointerup", () => { drag = null; });
    el.addEventListener("wheel", (e) => {
      e.preventDefault();
      this.orbit.radius *= Math.exp(e.deltaY * 0.001);
      this.render();
    }, { passive: false });
    el.addEventListener("dblclick", () => { this.fit(); this.render(); });
  }
}
