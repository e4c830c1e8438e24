// The camera sensors' controls (GET/PUT /api/cameras).
import { $, api, showError } from "./core.js";

// ---- camera sensors (GET/PUT /api/cameras) ---------------------------------------
// The controls show the values in use of the chosen camera ("both": the left one, else the
// right). A change sends only that field (+ "camera") as PUT; the slider is debounced
// (CAMERA_DEBOUNCE_MS). The answer (the values now in use) is shown; errors go to #messages.
const CAMERA_DEBOUNCE_MS = 200;
let cameraState = null;      // the last GET/PUT body
let cameraPending = {};      // fields waiting for the debounce timer
let cameraTimer = null;
let cameraInFlight = 0;

function cameraShown(state) {
  if (!state) return null;
  const target = $("camera-target").value;
  if (target === "left" || target === "right") return state[target];
  return state.left || state.right || null;
}

function renderCameras(state) {
  cameraState = state;
  const v = cameraShown(state);
  const ids = ["camera-exposure", "camera-exposure-range", "camera-gain", "camera-gain-range",
               "camera-aec", "camera-agc", "camera-flip-h", "camera-flip-v", "camera-test-pattern"];
  for (const id of ids) $(id).disabled = !v;
  const health = state && state.health ? state.health : {};
  const hel = $("camera-health");
  const bad = [];
  for (const c of ["left", "right"]) {
    const h = health[c];
    if (h && h.error) bad.push(c + ": " + h.error);
  }
  if (health.error) bad.push(health.error);
  hel.textContent = bad.length ? bad.join("; ") : (health.ok ? "sensors ok" : "");
  hel.className = "camera-health" + (bad.length ? " bad" : "");
  const form = $("camera-form");
  form.dataset.updated = String(Date.now());
  if (!v) return;
  // The exposures the sensor's timing takes (one row to one frame): the inputs end where PUT would refuse.
  if (Array.isArray(v.exposure_range_us) && v.exposure_range_us.length === 2) {
    const [lo, hi] = v.exposure_range_us;
    for (const id of ["camera-exposure", "camera-exposure-range"]) {
      $(id).min = String(Math.ceil(lo));
      $(id).max = String(Math.floor(hi));
    }
  }
  // Do not overwrite a value the user is still editing (pending debounce).
  if (!("exposure_us" in cameraPending) && typeof v.exposure_us === "number") {
    const us = Math.round(v.exposure_us);
    $("camera-exposure").value = String(us);
    $("camera-exposure-range").value = String(us);
  }
  if (!("gain" in cameraPending) && typeof v.gain === "number") {
    const g = Math.round(v.gain * 10) / 10;
    $("camera-gain").value = String(g);
    $("camera-gain-range").value = String(g);
  }
  $("camera-aec").checked = !!v.aec;
  $("camera-agc").checked = !!v.agc;
  $("camera-flip-h").checked = !!v.flip_h;
  $("camera-flip-v").checked = !!v.flip_v;
  const tp = v.test_pattern || "off";
  const sel = $("camera-test-pattern");
  if (![...sel.options].some((o) => o.value === tp)) {
    const opt = document.createElement("option");
    opt.value = opt.textContent = tp;
    sel.append(opt);
  }
  sel.value = tp;
  form.dataset.exposure = String(v.exposure_us);
}

async function loadCameras() {
  try {
    renderCameras(await api("GET", "/api/cameras"));
  } catch (e) {
    showError(e, { explain: { 503: (x) => "The camera sensors did not answer: " + x.detail + "." } });
  }
}

async function flushCameras() {
  if (cameraTimer) { clearTimeout(cameraTimer); cameraTimer = null; }
  const fields = cameraPending;
  cameraPending = {};
  if (!Object.keys(fields).length) return;
  const body = Object.assign({ camera: $("camera-target").value }, fields);
  const form = $("camera-form");
  cameraInFlight += 1;
  form.dataset.busy = "1";
  try {
    renderCameras(await api("PUT", "/api/cameras", body));
    form.dataset.applied = JSON.stringify(fields);
  } catch (e) {
    showError(e, { explain: {
      400: (x) => "That camera setting was refused: " + x.detail + ". The controls show the values in use.",
      503: (x) => "A camera is not answering, nothing was changed: " + x.detail + ".",
    } });
    await loadCameras();  // show what is really in use
  } finally {
    cameraInFlight -= 1;
    if (!cameraInFlight) delete form.dataset.busy;
  }
}

function queueCamera(fields, debounce) {
  Object.assign(cameraPending, fields);
  if (cameraTimer) clearTimeout(cameraTimer);
  cameraTimer = null;
  if (debounce) cameraTimer = setTimeout(flushCameras, CAMERA_DEBOUNCE_MS);
  else flushCameras();
}

export function initCameras() {
  const pairs = [["camera-exposure", "camera-exposure-range", "exposure_us", (x) => Math.round(x)],
                 ["camera-gain", "camera-gain-range", "gain", (x) => Math.round(x * 10) / 10]];
  for (const [numId, rangeId, key, norm] of pairs) {
    const num = $(numId), range = $(rangeId);
    const send = (text, debounce) => {
      const n = Number(text);
      if (text === "" || !Number.isFinite(n)) return;
      queueCamera({ [key]: norm(n) }, debounce);
    };
    range.addEventListener("input", () => { num.value = range.value; send(range.value, true); });
    range.addEventListener("change", () => { num.value = range.value; send(range.value, false); });
    num.addEventListener("input", () => { range.value = num.value; send(num.value, true); });
    num.addEventListener("change", () => { range.value = num.value; send(num.value, false); });
  }
  const checks = [["camera-aec", "aec"], ["camera-agc", "agc"], ["camera-flip-h", "flip_h"],
                  ["camera-flip-v", "flip_v"]];
  for (const [id, key] of checks) {
    $(id).addEventListener("change", (ev) => queueCamera({ [key]: ev.target.checked }, false));
  }
  $("camera-test-pattern").addEventListener("change", (ev) => {
    const v = ev.target.value;
    queueCamera({ test_pattern: v === "off" ? null : v }, false);
  });
  $("camera-target").addEventListener("change", () => { if (cameraState) renderCameras(cameraState); loadCameras(); });
  loadCameras();
}
