// drawstring studio: the page.  Plain JavaScript, no build step; everything it shows comes from
// the studio's API (docs/studio.md).  The options form is made from GET /api/options, so an
// option the server gains appears here as it is.  window.studio exposes the page's state for tests.

import { MeshView } from "./viewer.js";

const $ = (id) => document.getElementById(id);
const token = new URLSearchParams(location.search).get("token");

const state = {
  options: [],
  profiles: [],
  designs: new Map(),
  selected: null,
  ticked: [],
  uploads: new Map(),
  view: null,
  shownReport: "",
  estimates: 0,
};
window.studio = state;

function withToken(url) {
  if (!token) return url;
  return url + (url.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(token);
}

async function api(path, init = {}) {
  const headers = new Headers(init.headers || {});
  if (token) headers.set("Authorization", "Bearer " + token);
  const response = await fetch(path, { ...init, headers });
  const type = response.headers.get("content-type") || "";
  const body = type.includes("json") ? await response.json() : null;
  if (!response.ok) {
    let detail = body && body.detail !== undefined ? body.detail : response.statusText;
    if (typeof detail !== "string") detail = JSON.stringify(detail);
    const error = new Error(detail);
    error.status = response.status;
    throw error;
  }
  return body;
}

function element(tag, props = {}, ...children) {
  const el = document.createElement(tag);
  for (const [key, value] of Object.entries(props)) {
    if (value === undefined || value === null) continue;
    if (key === "class") el.className = value;
    else if (key === "dataset") Object.assign(el.dataset, value);
    else if (key.startsWith("on")) el.addEventListener(key.slice(2), value);
    else if (key in el) el[key] = value;
    else el.setAttribute(key, value);
  }
  for (const child of children) if (child !== null && child !== undefined) el.append(child);
  return el;
}

function showError(id, text) {
  const el = $(id);
  el.textContent = text || "";
  el.hidden = !text;
}

const fmt = (value, digits = 0) =>
  typeof value === "number" ? value.toLocaleString("en", { maximumFractionDigits: digits }) : String(value);

// ---------------------------------------------------------------------------------------------
// Targets and their 3D preview
// ---------------------------------------------------------------------------------------------

async function loadTargets() {
  const targets = await api("/api/targets");
  const select = $("target");
  const builtins = element("optgroup", { label: "built-in" });
  for (const t of targets) builtins.append(element("option", { value: t.name, title: t.description }, t.name));
  select.append(builtins, element("optgroup", { label: "uploaded", id: "uploaded-meshes", hidden: true }));
  select.value = targets.some((t) => t.name === "saddle") ? "saddle" : targets[0].name;
  select.addEventListener("change", () => previewTarget());
  await previewTarget();
}

async function previewTarget() {
  const value = $("target").value;
  showError("target-error", "");
  try {
    const upload = state.uploads.get(value);
    const preview = upload ? upload.preview : await api(`/api/targets/${encodeURIComponent(value)}/preview`);
    showPreview(preview);
  } catch (error) {
    showError("target-error", error.message);
  }
}

function showPreview(preview) {
  state.view.show(preview);
  const [x, y, z] = preview.extent_mm;
  let text = `${preview.name}: ${fmt(preview.triangles)} triangles, ${fmt(x)} × ${fmt(y)} × ${fmt(z)} mm as previewed (the design scales it to its size)`;
  if (preview.triangles_shown < preview.triangles) text += `; every ${Math.ceil(preview.triangles / preview.triangles_shown)}th triangle shown`;
  if (preview.notes && preview.notes.length) text += `. Repairs: ${preview.notes.join("; ")}`;
  $("target-info").textContent = text;
  state.previewed = preview.name;
}

async function uploadMesh(file) {
  showError("target-error", "");
  $("target-info").textContent = `checking ${file.name} …`;
  const form = new FormData();
  form.append("mesh", file);
  const repair = $("opt-repair");
  if (repair && repair.checked) form.append("repair", "true");
  try {
    const upload = await api("/api/meshes", { method: "POST", body: form });
    state.uploads.set(upload.id, upload);
    const group = $("uploaded-meshes");
    group.hidden = false;
    if (![...group.children].some((o) => o.value === upload.id)) {
      group.append(element("option", { value: upload.id }, upload.file));
    }
    $("target").value = upload.id;
    showPreview(upload.preview);
  } catch (error) {
    state.view.clear();
    $("target-info").textContent = "";
    showError("target-error", `${file.name} is refused: ${error.message}`);
  }
}

// ---------------------------------------------------------------------------------------------
// The options form, made from GET /api/options
// ---------------------------------------------------------------------------------------------

const LABELS = {
  size_mm: "size (mm)",
  thickness_mm: "thickness (mm)",
  min_gap_angle_deg: "least gap angle (°)",
  cad: "solids and fabrication files",
  simulate: "simulate the pull",
  co_optimize: "co-optimize",
};
const label = (spec) => LABELS[spec.name] || spec.name.replace(/_/g, " ");

function inputFor(spec, index) {
  const id = index === undefined ? `opt-${spec.name}` : `opt-${spec.name}-${index}`;
  const value = index === undefined ? spec.default : spec.default ? spec.default[index] : null;
  if (spec.name === "profile") {
    return element("select", { id, name: spec.name });
  }
  if (spec.kind === "bool") {
    return element("input", { id, type: "checkbox", name: spec.name, checked: Boolean(value) });
  }
  if (spec.choices) {
    const select = element("select", { id, name: spec.name });
    if (spec.optional) select.append(element("option", { value: "" }, "(default)"));
    for (const choice of spec.choices) select.append(element("option", { value: String(choice) }, String(choice)));
    select.value = value === null || value === undefined ? "" : String(value);
    return select;
  }
  const numeric = spec.kind === "int" || spec.kind === "float";
  return element("input", {
    id,
    name: spec.name,
    type: numeric ? "number" : "text",
    step: spec.kind === "int" ? "1" : "any",
    class: index === undefined ? "" : "part",
    value: value === null || value === undefined ? "" : String(value),
  });
}

function buildOptions() {
  for (const spec of state.options) {
    const parts = spec.count
      ? Array.from({ length: spec.count }, (_, i) => inputFor(spec, i))
      : [inputFor(spec)];
    const box = spec.main ? $("main-options") : $("more-options");
    const title = `${spec.flag}: ${spec.help}`;
    box.append(
      element("label", { htmlFor: parts[0].id, title }, label(spec)),
      element("div", { class: "inputs", title }, ...parts),
    );
  }
  fillProfiles();
  $("options").addEventListener("input", () => optionsChanged());
  $("options").addEventListener("change", () => optionsChanged());
}

function fillProfiles(selected) {
  const select = $("opt-profile");
  if (!select) return;
  const keep = selected || select.value || "fdm-dual";
  select.replaceChildren(
    ...state.profiles.map((p) =>
      element("option", { value: p.name, title: p.description }, p.uploaded ? `${p.title} (${p.file})` : p.name)),
  );
  select.value = state.profiles.some((p) => p.name === keep) ? keep : state.profiles[0].name;
  profileDefaults();
}

function profileDefaults() {
  const profile = state.profiles.find((p) => p.name === $("opt-profile").value);
  if (!profile) return;
  for (const spec of state.options) {
    if (!spec.profile_default) continue;
    const input = $(`opt-${spec.name}`);
    const value = profile.defaults[spec.name];
    if (input && value !== undefined) input.placeholder = `${value} (profile)`;
  }
}

function readOne(spec, input) {
  if (spec.name === "profile" || spec.choices) return input.value === "" ? undefined : spec.kind === "int" ? Number(input.value) : input.value;
  if (spec.kind === "bool") return input.checked;
  if (input.value.trim() === "") return undefined;
  if (spec.kind === "int" || spec.kind === "float") {
    const number = Number(input.value);
    return Number.isFinite(number) ? number : input.value;
  }
  return input.value;
}

// The options that differ from their defaults, as POST /api/designs takes them.
function collect() {
  const out = {};
  for (const spec of state.options) {
    let value;
    if (spec.count) {
      const parts = Array.from({ length: spec.count }, (_, i) => readOne(spec, $(`opt-${spec.name}-${i}`)));
      if (parts.every((p) => p === undefined)) continue;
      value = parts.map((p) => (p === undefined ? null : p));
    } else {
      value = readOne(spec, $(`opt-${spec.name}`));
      if (value === undefined) continue;
    }
    if (JSON.stringify(value) === JSON.stringify(spec.default)) continue;
    out[spec.name] = value;
  }
  return out;
}

let estimateTimer = null;
function optionsChanged() {
  profileDefaults();
  clearTimeout(estimateTimer);
  estimateTimer = setTimeout(updateEstimate, 200);
}

async function updateEstimate() {
  const asked = JSON.stringify(collect());
  try {
    const e = await api("/api/estimate", { method: "POST", headers: { "Content-Type": "application/json" }, body: asked });
    if (asked !== JSON.stringify(collect())) return; // the form moved on meanwhile
    showError("options-error", "");
    $("run").disabled = false;
    const box = $("estimate");
    if (e.note) {
      box.textContent = `${e.profile}, ${fmt(e.size_mm)} mm, ${fmt(e.tiles)} tiles: ${e.note}`;
    } else {
      const beds = e.beds ? `, at least ${e.beds.at_least} ${e.beds.at_least === 1 ? e.beds.of.replace(/s$/, "") : e.beds.of} (${e.beds.bed_mm.join(" × ")} mm)` : "";
      box.replaceChildren(
        `Roughly, for ${fmt(e.size_mm)} mm and ${fmt(e.tiles)} tiles of ${e.profile}: `,
        element("b", {}, `${fmt(e.mass_g / 1000, 2)} kg`), ", ",
        element("b", {}, `${fmt(e.cost, 2)} ${e.currency}`), " of material, ",
        element("b", {}, `${fmt(e.hours, 1)} h`), ` of ${e.basis}${beds}.`,
      );
    }
    state.estimates += 1;
  } catch (error) {
    if (asked !== JSON.stringify(collect())) return;
    $("estimate").textContent = "";
    showError("options-error", error.message);
    $("run").disabled = error.status === 422;
  }
}

async function uploadProfile(file) {
  showError("profile-error", "");
  const form = new FormData();
  form.append("profile", file);
  try {
    const profile = await api("/api/profiles", { method: "POST", body: form });
    state.profiles = await api("/api/profiles");
    const spec = state.options.find((s) => s.name === "profile");
    if (spec && !spec.choices.includes(profile.name)) spec.choices.push(profile.name);
    fillProfiles(profile.name);
    optionsChanged();
  } catch (error) {
    showError("profile-error", `${file.name} is refused: ${error.message}`);
  }
}

// ---------------------------------------------------------------------------------------------
// Running designs
// ---------------------------------------------------------------------------------------------

async function run() {
  showError("options-error", "");
  const form = new FormData();
  form.append("target", $("target").value);
  form.append("options", JSON.stringify(collect()));
  $("run").disabled = true;
  try {
    const record = await api("/api/designs", { method: "POST", body: form });
    merge(record);
    select(record.id);
    $("run-note").textContent = `queued as ${record.id}`;
  } catch (error) {
    showError("options-error", error.message);
  } finally {
    $("run").disabled = false;
  }
}

function merge(record) {
  const known = state.designs.get(record.id);
  if (known && known.rev > record.rev) return;
  state.designs.set(record.id, record);
  renderRows();
  if (state.selected === record.id) renderResult();
}

function describe(record) {
  const o = record.options || {};
  const parts = [];
  if (o.grid) parts.push(`${o.grid[0]} × ${o.grid[1]} grid`);
  else parts.push(o.tiles ? `${o.tiles} tiles` : "profile's tiles");
  if (o.size_mm) parts.push(`${fmt(o.size_mm)} mm`);
  parts.push(o.profile && o.profile.startsWith("upload:") ? "own profile" : o.profile || "fdm-dual");
  if (o.hinges === "top") parts.push("top hinges");
  if (o.cad === false) parts.push("no CAD");
  if (o.simulate === false) parts.push("no simulation");
  return parts.join(" · ");
}

function statusText(record) {
  const pct = `${Math.round(100 * record.progress)} %`;
  if (record.status === "running") return `running: ${record.stage || "starting"} (${pct})`;
  if (record.status === "queued") return "queued";
  if (record.status === "done") return record.exit_status ? `done (exit ${record.exit_status}): ${record.message}` : `done (100 %): ${record.message}`;
  return `${record.status}: ${record.message}`;
}

function stateCell(record) {
  return element(
    "td",
    { class: `state status-${record.status} exit-${record.exit_status}`, dataset: { status: record.status, progress: String(record.progress) } },
    element("progress", { max: 1, value: record.progress }),
    element("span", { class: "label" }, statusText(record)),
  );
}

function actionButtons(record, big) {
  const id = record.id;
  const buttons = [];
  const act = (text, fn, name) => element("button", { type: "button", class: name, onclick: (e) => { e.stopPropagation(); fn(); } }, text);
  if (record.status === "queued" || record.status === "running") buttons.push(act("Cancel", () => post(`/api/designs/${id}/cancel`), "cancel"));
  else buttons.push(act("Run again", () => post(`/api/designs/${id}/run`), "rerun"));
  if (big && record.has_design) {
    buttons.push(element("a", { class: "button", id: "download-zip", href: withToken(`/api/designs/${id}/files.zip`), download: "" }, "Download zip"));
    if (record.has_fabrication) {
      buttons.push(element("a", { class: "button", id: "download-fabrication", href: withToken(`/api/designs/${id}/fabrication.zip`), download: "" }, "fabrication/ only"));
    }
  }
  if (big) buttons.push(element("a", { class: "button", href: withToken(`/api/designs/${id}/log`), target: "_blank" }, "Log"));
  buttons.push(act("Remove", () => removeDesign(id), "remove"));
  return buttons;
}

async function post(path) {
  try {
    merge(await api(path, { method: "POST" }));
  } catch (error) {
    alert(error.message);
  }
}

async function removeDesign(id) {
  if (!confirm("Remove this design and its files?")) return;
  try {
    await api(`/api/designs/${id}`, { method: "DELETE" });
    forget(id);
  } catch (error) {
    alert(error.message);
  }
}

function forget(id) {
  state.designs.delete(id);
  state.ticked = state.ticked.filter((t) => t !== id);
  if (state.selected === id) {
    state.selected = null;
    $("result").hidden = true;
  }
  renderRows();
}

function renderRows() {
  const rows = [...state.designs.values()].sort((a, b) => b.created - a.created);
  $("no-designs").hidden = rows.length > 0;
  $("design-rows").replaceChildren(
    ...rows.map((record) =>
      element(
        "tr",
        { dataset: { id: record.id }, class: record.id === state.selected ? "selected" : "", onclick: () => select(record.id) },
        element("td", {}, element("input", {
          type: "checkbox", class: "tick", checked: state.ticked.includes(record.id), disabled: !record.numbers,
          title: record.numbers ? "tick two designs to compare them" : "only finished designs compare",
          onclick: (e) => e.stopPropagation(),
          onchange: (e) => tick(record.id, e.target.checked),
        })),
        element("td", {}, element("span", { class: "name" }, record.name), element("span", { class: "what" }, describe(record))),
        stateCell(record),
        element("td", { class: "actions" }, ...actionButtons(record, false)),
      )),
  );
  const running = rows.filter((r) => r.status === "running").length;
  const queued = rows.filter((r) => r.status === "queued").length;
  $("queue").textContent = running || queued ? `${running} running, ${queued} queued` : "";
  $("compare").disabled = state.ticked.length !== 2;
}

function tick(id, on) {
  state.ticked = state.ticked.filter((t) => t !== id);
  if (on) state.ticked.push(id);
  if (state.ticked.length > 2) state.ticked.shift();
  renderRows();
}

function select(id) {
  state.selected = id;
  state.shownReport = "";
  renderRows();
  renderResult();
}

function renderResult() {
  const record = state.designs.get(state.selected);
  if (!record) return;
  $("result").hidden = false;
  $("result-title").textContent = `${record.name} · ${describe(record)}`;
  $("result-actions").replaceChildren(...actionButtons(record, true));
  const active = record.status === "queued" || record.status === "running";
  $("result-progress").replaceChildren(
    ...(active ? [element("progress", { id: "result-bar", max: 1, value: record.progress })] : []),
  );
  $("result-message").textContent = statusText(record);
  $("result-message").className = `status-${record.status}`;
  const frame = $("report");
  const key = `${record.id}:${record.finished}:${record.has_design}`;
  if (record.has_design && !active) {
    if (state.shownReport !== key) {
      frame.src = withToken(`/api/designs/${record.id}/report`);
      state.shownReport = key;
    }
    frame.hidden = false;
  } else {
    frame.hidden = true;
    frame.removeAttribute("src");
    state.shownReport = "";
  }
}

// ---------------------------------------------------------------------------------------------
// Comparing two designs
// ---------------------------------------------------------------------------------------------

function compare() {
  const [a, b] = state.ticked.map((id) => state.designs.get(id));
  if (!a || !b || !a.numbers || !b.numbers) return;
  const head = element("tr", {}, element("th", {}, ""), element("th", {}, `${a.name} · ${describe(a)}`), element("th", {}, `${b.name} · ${describe(b)}`));
  const rows = a.numbers.map((row, i) => {
    const other = b.numbers[i] || { value: null };
    const show = (v) => (v === null || v === undefined ? "–" : typeof v === "boolean" ? (v ? "yes" : "no") : `${fmt(v, 6)}${row.unit ? " " + row.unit : ""}`);
    return element(
      "tr",
      { class: JSON.stringify(row.value) !== JSON.stringify(other.value) ? "differs" : "" },
      element("th", {}, row.label),
      element("td", { class: "num" }, show(row.value)),
      element("td", { class: "num" }, show(other.value)),
    );
  });
  $("compare-table").replaceChildren(element("thead", {}, head), element("tbody", {}, ...rows));
  $("report-a").src = withToken(`/api/designs/${a.id}/report`);
  $("report-b").src = withToken(`/api/designs/${b.id}/report`);
  $("comparison").hidden = false;
  $("comparison").scrollIntoView({ behavior: "smooth" });
}

// ---------------------------------------------------------------------------------------------
// Start
// ---------------------------------------------------------------------------------------------

function listen() {
  const source = new EventSource(withToken("/api/events"));
  source.addEventListener("design", (e) => merge(JSON.parse(e.data)));
  source.addEventListener("removed", (e) => forget(JSON.parse(e.data).id));
  source.addEventListener("open", () => { state.connected = true; });
  source.addEventListener("error", () => { state.connected = false; });
}

async function start() {
  state.view = new MeshView($("target-view"));
  $("mesh-file").addEventListener("change", (e) => { if (e.target.files[0]) uploadMesh(e.target.files[0]); });
  $("profile-file").addEventListener("change", (e) => { if (e.target.files[0]) uploadProfile(e.target.files[0]); });
  $("run").addEventListener("click", run);
  $("compare").addEventListener("click", compare);
  $("close-compare").addEventListener("click", () => { $("comparison").hidden = true; });
  try {
    const [status, options, profiles] = await Promise.all([api("/api/status"), api("/api/options"), api("/api/profiles")]);
    $("status").textContent = `drawstring ${status.version} · ${status.max_running} design${status.max_running === 1 ? "" : "s"} at a time · uploads up to ${status.upload_limit_bytes / 2 ** 20} MiB`;
    state.options = options;
    state.profiles = profiles;
    buildOptions();
    listen();
    for (const record of await api("/api/designs")) merge(record);
    await loadTargets();
    await updateEstimate();
    state.ready = true;
  } catch (error) {
    $("status").textContent = `the studio did not answer: ${error.message}`;
  }
}

start();
