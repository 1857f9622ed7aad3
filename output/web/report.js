// drawstring report: interactive 3D view of a design (flat, assembled, deployment).
// Reads the JSON block #drawstring-data written by drawstring.fabrication.report and the
// three.js namespace the page puts on globalThis.THREE.  Z is up; lengths in mm.
// window.drawstringView exposes the view's state (frame, selection, render count) for tests.

const THREE = globalThis.THREE;
const data = JSON.parse(document.getElementById("drawstring-data").textContent);
const $ = (id) => document.getElementById(id);

// Vertex order of a tile (contracts): top corners 0..3 counter-clockwise, bottom 4..7 under them.
// Faces wound outwards: top, bottom, then side k = (top k, bottom k, bottom k+1, top k+1).
const FACES = [[0, 1, 2, 3], [4, 7, 6, 5]];
for (let k = 0; k < 4; k++) FACES.push([k, 4 + k, 4 + ((k + 1) % 4), (k + 1) % 4]);
const TRIS = [];
for (const f of FACES) TRIS.push([f[0], f[1], f[2]], [f[0], f[2], f[3]]);
const EDGES = [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]];
const SIDE_NAMES = ["bottom", "right", "top", "left"];

const state = {
  ready: false,
  renders: 0,
  pose: null,
  frame: null,
  frameCount: data.frames ? data.frames.length : 0,
  tileCount: data.tiles,
  selected: -1,
  colourFit: false,
  message: "",
};
window.drawstringView = state;

function poseArray() {
  if (state.frame !== null && data.frames) return data.frames[state.frame];
  return data.poses[state.pose];
}

// ---------- small helpers on the flat (T * 24) coordinate arrays ----------
function vertex(P, t, v, out) {
  const o = t * 24 + v * 3;
  out.set(P[o], P[o + 1], P[o + 2]);
  return out;
}

function bounds(P) {
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < P.length; i += 3) {
    for (let a = 0; a < 3; a++) {
      if (P[i + a] < lo[a]) lo[a] = P[i + a];
      if (P[i + a] > hi[a]) hi[a] = P[i + a];
    }
  }
  const centre = new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
  const radius = 0.5 * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
  return { centre, radius };
}

function medianEdge(P) {
  const a = new THREE.Vector3();
  const b = new THREE.Vector3();
  const lengths = [];
  for (let t = 0; t < data.tiles; t++) {
    lengths.push(vertex(P, t, 0, a).distanceTo(vertex(P, t, 1, b)));
  }
  lengths.sort((x, y) => x - y);
  return lengths[Math.floor(lengths.length / 2)] || 1;
}

function sideCentre(P, t, k, out) {
  out.set(0, 0, 0);
  const tmp = new THREE.Vector3();
  for (const v of [k, (k + 1) % 4, 4 + ((k + 1) % 4), 4 + k]) out.add(vertex(P, t, v, tmp));
  return out.multiplyScalar(0.25);
}

function tileCentre(P, t, out) {
  out.set(0, 0, 0);
  const tmp = new THREE.Vector3();
  for (let v = 0; v < 8; v++) out.add(vertex(P, t, v, tmp));
  return out.multiplyScalar(0.125);
}

function topCentreAndNormal(P, t, centre, normal) {
  const p = [0, 1, 2, 3].map((v) => vertex(P, t, v, new THREE.Vector3()));
  centre.copy(p[0]).add(p[1]).add(p[2]).add(p[3]).multiplyScalar(0.25);
  const d1 = p[2].clone().sub(p[0]);
  const d2 = p[3].clone().sub(p[1]);
  normal.crossVectors(d1, d2).normalize();
}

// ---------- scene ----------
function tileColour(t) {
  const c = new THREE.Color();
  c.setHSL((0.08 + ((t * 0.618034) % 1) * 0.16) % 1, 0.45, 0.62 + 0.1 * ((t * 7) % 3) / 2);
  return c;
}
const SELECTED = new THREE.Color(0xf59f00);
const NEIGHBOUR = new THREE.Color(0x20c997);

// Distance from the target (data.fit, mm per tile): viridis at 0, 1/4, 1/2, 3/4 and 1 of the
// scale, as fit.png draws it; the scale runs to the largest tile's mean or the quality level.
const FIT_STOPS = [0x440154, 0x3b528b, 0x21918c, 0x5ec962, 0xfde725].map((c) => new THREE.Color(c));
const fitScale = data.fit ? Math.max(data.fit.level, ...data.fit.mean, 1e-6) : 1;
function fitColour(d) {
  const x = Math.min(Math.max(d / fitScale, 0), 1) * (FIT_STOPS.length - 1);
  const k = Math.min(Math.floor(x), FIT_STOPS.length - 2);
  return FIT_STOPS[k].clone().lerp(FIT_STOPS[k + 1], x - k);
}

function build() {
  const host = $("view");
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
  host.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xf4f5f7);
  const camera = new THREE.PerspectiveCamera(40, 1, 0.1, 1e6);
  camera.up.set(0, 0, 1);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8f99, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.8);
  sun.position.set(0.4, -0.6, 1);
  camera.add(sun);
  scene.add(camera);

  // Start assembled (the shape the user asked for); the deployment slider then sits at its end.
  const start = data.poses.assembled || data.frames ? "assembled" : "flat";
  if (data.frames) state.frame = start === "flat" ? 0 : state.frameCount - 1;
  else state.pose = start;

  const T = data.tiles;
  // Tiles: one non-indexed triangle soup, 12 triangles per tile, flat shaded.
  const tilePos = new Float32Array(T * 36 * 3);
  const tileCol = new Float32Array(T * 36 * 3);
  const tileGeom = new THREE.BufferGeometry();
  tileGeom.setAttribute("position", new THREE.BufferAttribute(tilePos, 3));
  tileGeom.setAttribute("color", new THREE.BufferAttribute(tileCol, 3));
  const tileMat = new THREE.MeshLambertMaterial({
    vertexColors: true, flatShading: true, side: THREE.DoubleSide,
    polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
  });
  const tiles = new THREE.Mesh(tileGeom, tileMat);
  scene.add(tiles);

  const edgePos = new Float32Array(T * 24 * 3);
  const edgeGeom = new THREE.BufferGeometry();
  edgeGeom.setAttribute("position", new THREE.BufferAttribute(edgePos, 3));
  const edges = new THREE.LineSegments(edgeGeom, new THREE.LineBasicMaterial({ color: 0x3b3f46, transparent: T > 400, opacity: T > 400 ? 0.3 : 1 }));
  scene.add(edges);

  const P0 = poseArray();
  const L = medianEdge(P0);
  const onTop = (colour) => new THREE.MeshBasicMaterial({ color: colour, depthTest: false, transparent: true });

  const H = data.hinges.length;
  const hinges = new THREE.InstancedMesh(new THREE.SphereGeometry(0.09 * L, 8, 6), new THREE.MeshLambertMaterial({ color: 0x1c7ed6 }), Math.max(H, 1));
  hinges.count = H;
  scene.add(hinges);

  const steps = data.route ? data.route.steps : [];
  const nRoute = steps.length ? steps.length * 3 : 0;
  const route = new THREE.InstancedMesh(new THREE.CylinderGeometry(1, 1, 1, 8, 1, true), onTop(0xe03131), Math.max(nRoute, 1));
  route.count = nRoute;
  route.renderOrder = 10;
  scene.add(route);

  const lifts = data.route ? data.route.lift : [];
  const liftBalls = new THREE.InstancedMesh(new THREE.SphereGeometry(0.22 * L, 16, 12), onTop(0xa61e4d), Math.max(lifts.length, 1));
  const liftSticks = new THREE.InstancedMesh(new THREE.CylinderGeometry(1, 1, 1, 8, 1, true), onTop(0xa61e4d), Math.max(lifts.length, 1));
  liftBalls.count = lifts.length;
  liftSticks.count = lifts.length;
  liftBalls.renderOrder = liftSticks.renderOrder = 11;
  scene.add(liftBalls, liftSticks);

  const groups = { tiles: [tiles], edges: [edges], hinges: [hinges], route: [route], lifts: [liftBalls, liftSticks] };

  // ---------- per-pose update ----------
  const m = new THREE.Matrix4();
  const q = new THREE.Quaternion();
  const yAxis = new THREE.Vector3(0, 1, 0);
  const va = new THREE.Vector3();
  const vb = new THREE.Vector3();
  let centre = new THREE.Vector3();

  function segment(mesh, i, a, b, radius) {
    const d = vb.copy(b).sub(a);
    const len = d.length();
    q.setFromUnitVectors(yAxis, len > 0 ? d.clone().divideScalar(len) : yAxis);
    m.compose(a.clone().add(b).multiplyScalar(0.5), q, new THREE.Vector3(radius, Math.max(len, 1e-9), radius));
    mesh.setMatrixAt(i, m);
  }

  function update() {
    const P = poseArray();
    centre = bounds(P).centre;
    const at = (t, v) => vertex(P, t, v, new THREE.Vector3()).sub(centre);
    let o = 0;
    for (let t = 0; t < T; t++) {
      for (const tri of TRIS) for (const v of tri) { at(t, v).toArray(tilePos, o); o += 3; }
    }
    o = 0;
    for (let t = 0; t < T; t++) {
      for (const [a, b] of EDGES) { at(t, a).toArray(edgePos, o); at(t, b).toArray(edgePos, o + 3); o += 6; }
    }
    tileGeom.attributes.position.needsUpdate = true;
    tileGeom.computeBoundingSphere();
    edgeGeom.attributes.position.needsUpdate = true;
    edgeGeom.computeBoundingSphere();

    data.hinges.forEach(([ta, ca, tb, cb, side], i) => {
      const pos = (t, c) => (side === 1 ? at(t, 4 + c) : side === 0 ? at(t, c) : at(t, c).add(at(t, 4 + c)).multiplyScalar(0.5));
      m.makeTranslation(pos(ta, ca).add(pos(tb, cb)).multiplyScalar(0.5));
      hinges.setMatrixAt(i, m);
    });
    hinges.instanceMatrix.needsUpdate = true;

    if (nRoute) {
      const pts = [];
      for (const [, t, enter, leave] of steps) {
        pts.push(sideCentre(P, t, enter, new THREE.Vector3()).sub(centre));
        pts.push(tileCentre(P, t, new THREE.Vector3()).sub(centre));
        pts.push(sideCentre(P, t, leave, new THREE.Vector3()).sub(centre));
      }
      for (let i = 0; i < pts.length; i++) segment(route, i, pts[i], pts[(i + 1) % pts.length], 0.035 * L);
      route.instanceMatrix.needsUpdate = true;
    }
    const c = new THREE.Vector3();
    const n = new THREE.Vector3();
    lifts.forEach(([, t], i) => {
      topCentreAndNormal(P, t, c, n);
      c.sub(centre);
      const tip = c.clone().addScaledVector(n, 1.2 * L);
      m.makeTranslation(tip);
      liftBalls.setMatrixAt(i, m);
      segment(liftSticks, i, c, tip, 0.035 * L);
    });
    liftBalls.instanceMatrix.needsUpdate = true;
    liftSticks.instanceMatrix.needsUpdate = true;
    for (const mesh of [hinges, route, liftBalls, liftSticks]) mesh.computeBoundingSphere();
  }

  function paint() {
    const neighbours = state.selected >= 0 ? new Set(data.neighbours[state.selected]) : new Set();
    for (let t = 0; t < T; t++) {
      const own = state.colourFit && data.fit ? fitColour(data.fit.mean[t]) : tileColour(t);
      const c = t === state.selected ? SELECTED : neighbours.has(t) ? NEIGHBOUR : own;
      for (let i = 0; i < 36; i++) c.toArray(tileCol, (t * 36 + i) * 3);
    }
    tileGeom.attributes.color.needsUpdate = true;
  }

  // ---------- camera: a small orbit control (drag: turn, shift/right drag: pan, wheel: zoom) ----------
  const orbit = { target: new THREE.Vector3(), radius: 1, theta: -Math.PI / 3, phi: 1.0 };
  function fit() {
    let r = 0;
    for (const P of Object.values(data.poses)) if (P) r = Math.max(r, bounds(P).radius);
    if (data.frames) r = Math.max(r, bounds(data.frames[0]).radius, bounds(data.frames[data.frames.length - 1]).radius);
    // Distance at which the bounding sphere just fits the smaller of the two view angles.
    const half = Math.min(camera.fov, (2 * Math.atan(Math.tan((camera.fov * Math.PI) / 360) * camera.aspect) * 180) / Math.PI) / 2;
    orbit.radius = ((r || 1) / Math.sin((half * Math.PI) / 180)) * 0.85;
    orbit.target.set(0, 0, 0);
    camera.near = orbit.radius / 1000;
    camera.far = orbit.radius * 100;
    camera.updateProjectionMatrix();
  }
  function placeCamera() {
    const s = Math.sin(orbit.phi);
    camera.position.set(s * Math.cos(orbit.theta), s * Math.sin(orbit.theta), Math.cos(orbit.phi))
      .multiplyScalar(orbit.radius).add(orbit.target);
    camera.lookAt(orbit.target);
  }

  let pending = false;
  function render() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => {
      pending = false;
      placeCamera();
      renderer.render(scene, camera);
      state.renders += 1;
    });
  }

  function resize() {
    const w = host.clientWidth || 600;
    const h = host.clientHeight || 400;
    renderer.setSize(w, h);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    render();
  }

  const el = renderer.domElement;
  let drag = null;
  el.addEventListener("contextmenu", (e) => e.preventDefault());
  el.addEventListener("pointerdown", (e) => {
    drag = { x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, pan: e.button === 2 || e.shiftKey || e.ctrlKey };
    el.setPointerCapture(e.pointerId);
  });
  el.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x;
    const dy = e.clientY - drag.y;
    drag.x = e.clientX;
    drag.y = e.clientY;
    if (drag.pan) {
      const scale = (2 * orbit.radius * Math.tan((camera.fov * Math.PI) / 360)) / el.clientHeight;
      const right = new THREE.Vector3().setFromMatrixColumn(camera.matrix, 0);
      const up = new THREE.Vector3().setFromMatrixColumn(camera.matrix, 1);
      orbit.target.addScaledVector(right, -dx * scale).addScaledVector(up, dy * scale);
    } else {
      orbit.theta -= dx * 0.008;
      orbit.phi = Math.min(Math.PI - 0.01, Math.max(0.01, orbit.phi - dy * 0.008));
    }
    render();
  });
  el.addEventListener("pointerup", (e) => {
    if (drag && Math.hypot(e.clientX - drag.x0, e.clientY - drag.y0) < 4) pickAt(e.clientX, e.clientY);
    drag = null;
  });
  el.addEventListener("wheel", (e) => {
    e.preventDefault();
    orbit.radius *= Math.exp(e.deltaY * 0.001);
    render();
  }, { passive: false });
  el.addEventListener("dblclick", () => { fit(); render(); });

  // ---------- picking ----------
  const ray = new THREE.Raycaster();
  function pickAt(x, y) {
    const r = el.getBoundingClientRect();
    const p = new THREE.Vector2(((x - r.left) / r.width) * 2 - 1, -((y - r.top) / r.height) * 2 + 1);
    ray.setFromCamera(p, camera);
    const hit = tiles.visible ? ray.intersectObject(tiles, false)[0] : undefined;
    select(hit ? Math.floor(hit.faceIndex / 12) : -1);
    return state.selected;
  }
  function select(t) {
    state.selected = t;
    const info = $("tile-info");
    if (t < 0) {
      info.textContent = "Click a tile to see its id and its neighbours.";
    } else {
      const nb = data.neighbours[t];
      const route = data.route ? data.route.steps.filter((s) => s[1] === t) : [];
      let text = `Tile ${t}: ${nb.length} neighbour${nb.length === 1 ? "" : "s"} (${data.neighbour_rule}): ${nb.join(", ") || "none"}.`;
      if (route.length) {
        text += " String: " + route.map((s) => `in through its ${SIDE_NAMES[s[2]]} side, out through its ${SIDE_NAMES[s[3]]} side`).join("; ") + ".";
      }
      if (lifts.some((l) => l[1] === t)) text += " Lift point: the string leaves through its top face here.";
      if (data.fit) text += ` Top face: ${data.fit.mean[t].toFixed(2)} mm from the target on average, ${data.fit.max[t].toFixed(2)} mm at most.`;
      info.textContent = text;
    }
    paint();
    render();
  }
  state.pickAt = pickAt;
  state.select = select;

  // ---------- controls ----------
  for (const [name, objs] of Object.entries(groups)) {
    const box = $("show-" + name);
    if (!box) continue;
    const apply = () => { for (const o of objs) o.visible = box.checked; render(); };
    box.addEventListener("change", apply);
    apply();
  }

  const fitBox = $("colour-fit");
  function setColourFit(on) {
    state.colourFit = Boolean(on && data.fit);
    if (fitBox) fitBox.checked = state.colourFit;
    const scale = $("fit-scale");
    if (scale) scale.hidden = !state.colourFit;
    if (state.colourFit) {
      $("fit-scale-label").textContent = `0 to ${fitScale.toFixed(2)} mm` +
        (data.fit.level > 0 ? `; quality level ${data.fit.level.toFixed(2)} mm (${data.fit.level_pct} % of a tile side)` : "");
    }
    paint();
    render();
  }
  state.setColourFit = setColourFit;
  if (fitBox) {
    fitBox.disabled = !data.fit;
    fitBox.addEventListener("change", () => setColourFit(fitBox.checked));
  }

  const slider = $("deploy");
  const label = $("deploy-label");
  function setFrame(k) {
    state.frame = Math.max(0, Math.min(state.frameCount - 1, k));
    slider.value = String(state.frame);
    const share = state.frameCount > 1 ? state.frame / (state.frameCount - 1) : 1;
    label.textContent = `frame ${state.frame + 1} of ${state.frameCount} (${Math.round(share * 100)} % deployed)`;
    update();
    render();
  }
  function setPose(name) {
    if (data.frames) {
      setFrame(name === "flat" ? 0 : state.frameCount - 1);
    } else {
      state.pose = name;
      update();
      render();
    }
    for (const b of document.querySelectorAll("[data-pose]")) b.classList.toggle("on", b.dataset.pose === name);
  }
  state.setFrame = setFrame;
  state.setPose = setPose;
  for (const b of document.querySelectorAll("[data-pose]")) {
    b.disabled = !data.frames && !data.poses[b.dataset.pose];
    b.addEventListener("click", () => setPose(b.dataset.pose));
  }
  let playing = null;
  const play = $("play");
  if (data.frames) {
    slider.max = String(state.frameCount - 1);
    slider.addEventListener("input", () => {
      setFrame(Number(slider.value));
      for (const b of document.querySelectorAll("[data-pose]")) b.classList.remove("on");
    });
    play.addEventListener("click", () => {
      if (playing) { clearInterval(playing); playing = null; play.textContent = "Play"; return; }
      if (state.frame >= state.frameCount - 1) setFrame(0);
      play.textContent = "Pause";
      playing = setInterval(() => {
        if (state.frame >= state.frameCount - 1) { clearInterval(playing); playing = null; play.textContent = "Play"; return; }
        setFrame(state.frame + 1);
      }, Math.max(30, 3000 / state.frameCount));
    });
  } else {
    slider.disabled = true;
    play.disabled = true;
  }

  fit();
  if (data.frames) setFrame(start === "flat" ? 0 : state.frameCount - 1);
  else update();
  for (const b of document.querySelectorAll("[data-pose]")) b.classList.toggle("on", b.dataset.pose === start);
  paint();
  select(-1);
  new ResizeObserver(resize).observe(host);
  resize();
  fit();
  render();
  requestAnimationFrame(() => requestAnimationFrame(() => { state.ready = true; }));
}

const hasGeometry = data.tiles > 0 && (data.frames || Object.values(data.poses).some((p) => p));
if (!hasGeometry) {
  $("view").classList.add("empty");
  $("view").textContent = "No tile geometry in this design yet (assembled.obj, flat.obj and deploy.npz are all missing), so there is nothing to show in 3D.";
  state.message = "no geometry";
  for (const el of document.querySelectorAll(".controls input, .controls button, .deploy input, .deploy button")) el.disabled = true;
  state.ready = true;
} else {
  build();
}
