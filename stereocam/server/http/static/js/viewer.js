// The capture viewer (issue 13, item 3): one capture's four stored images (raw and rectified, left
// and right), zoom (wheel, buttons, + - 0 keys) and pan (drag), and under the pointer the pixel's
// x, y and channel values read from the stored lossless PNG (never from a JPEG), plus replay into
// the virtual camera.
//
// Drawing: the PNG is decoded without colour conversion (createImageBitmap, colorSpaceConversion
// "none") onto a canvas, scaled by `zoom` (CSS px per image px) with its origin at (tx, ty) CSS px in
// the stage, without smoothing: image pixel (u, v) covers [tx + u*zoom, tx + (u+1)*zoom) across.
// The canvas carries data-zoom, data-tx, data-ty, data-image and data-loaded (tests read them).
//
// A recording (openRecording) opens in the same viewer, one stored frame at a time: its left or right
// raw image, stepped with the ⏮ ◀ ▶ ⏭ buttons or ←/→ (Home/End: first/last), "frame i / N" shown,
// read from GET /api/recordings/{id}/frames/{i}/{side}.png (the PNG as recorded, X-Frames the count,
// X-Color gray|rgb). The zoom and pan stay while stepping. The canvas then also carries
// data-index (the frame shown) and data-frames.
import { $, api, action, showMessage } from "./core.js";

const IMAGES = [["raw_left", "raw left"], ["raw_right", "raw right"], ["rect_left", "rectified left"],
                ["rect_right", "rectified right"]];
const ZOOM_STEP = 1.25;
const ZOOM_MAX = 64;

let dlg = null;
let el = {};
const SIDES = [["left", "left"], ["right", "right"]];
const state = {
  id: null, meta: null, image: null, bitmap: null, pixels: null, ypixels: null, w: 0, h: 0,
  zoom: 1, tx: 0, ty: 0, drag: null, pointer: null, loadSeq: 0,
  kind: "capture", index: 0, frames: 0, color: "rgb",  // kind "recording": stepping through its frames
};

function button(text, testid, title, onClick) {
  const b = document.createElement("button");
  b.type = "button";
  b.textContent = text;
  b.setAttribute("data-testid", testid);
  if (title) { b.title = title; b.setAttribute("aria-label", title); }
  b.addEventListener("click", onClick);
  return b;
}

function build() {
  dlg = document.createElement("dialog");
  dlg.className = "cv";
  dlg.id = "capture-viewer";
  dlg.setAttribute("data-testid", "capture-viewer");
  dlg.setAttribute("aria-label", "capture viewer");
  const bar = document.createElement("div");
  bar.className = "cv-bar";
  const title = document.createElement("span");
  title.className = "cv-title";
  title.setAttribute("data-testid", "cv-title");
  const choose = document.createElement("span");
  choose.setAttribute("role", "group");
  choose.setAttribute("aria-label", "image");
  el.choices = {};
  for (const [name, label] of IMAGES) {
    const b = button(label, "cv-image-" + name, null, () => show(name));
    b.setAttribute("aria-pressed", "false");
    el.choices[name] = b;
    choose.append(b);
  }
  const sides = document.createElement("span");
  sides.setAttribute("role", "group");
  sides.setAttribute("aria-label", "camera");
  el.sides = {};
  for (const [name, label] of SIDES) {
    const b = button(label, "cv-side-" + name, null, () => { state.image = name; showFrame(state.index); });
    b.setAttribute("aria-pressed", "false");
    el.sides[name] = b;
    sides.append(b);
  }
  const steps = document.createElement("span");
  steps.className = "cv-steps";
  steps.setAttribute("role", "group");
  steps.setAttribute("aria-label", "frames");
  const frameText = document.createElement("span");
  frameText.className = "cv-frame";
  frameText.setAttribute("data-testid", "cv-frame");
  frameText.setAttribute("aria-live", "polite");
  frameText.title = "the frame shown / the last frame (the first is 0)";
  el.stepButtons = {
    first: button("⏮", "cv-first", "first frame (Home)", () => showFrame(0)),
    prev: button("◀", "cv-prev", "previous frame (←)", () => showFrame(state.index - 1)),
    next: button("▶", "cv-next", "next frame (→)", () => showFrame(state.index + 1)),
    last: button("⏭", "cv-last", "last frame (End)", () => showFrame(state.frames - 1)),
  };
  steps.append(el.stepButtons.first, el.stepButtons.prev, frameText, el.stepButtons.next, el.stepButtons.last);
  const zoomOut = button("−", "cv-zoom-out", "zoom out (−)", () => zoomBy(1 / ZOOM_STEP));
  const zoomText = document.createElement("span");
  zoomText.className = "cv-zoom";
  zoomText.setAttribute("data-testid", "cv-zoom");
  const zoomIn = button("+", "cv-zoom-in", "zoom in (+)", () => zoomBy(ZOOM_STEP));
  const fit = button("fit", "cv-fit", "fit the image to the window (0)", () => { fitView(); draw(); });
  const one = button("1:1", "cv-one", "one image pixel per screen pixel", () => zoomTo(1 / (window.devicePixelRatio || 1)));
  const replay = button("Replay", "cv-replay", "send this capture's raw pair through the fabric (virtual camera)",
                        (ev) => replayCapture(state.id, ev.currentTarget));
  const png = document.createElement("a");
  png.className = "btn";
  png.textContent = "PNG";
  png.setAttribute("data-testid", "cv-download");
  const close = button("×", "cv-close", "close (Esc)", () => dlg.close());
  bar.append(title, choose, sides, steps, zoomOut, zoomText, zoomIn, fit, one, replay, png, close);
  const stage = document.createElement("div");
  stage.className = "cv-stage";
  stage.setAttribute("data-testid", "cv-stage");
  const canvas = document.createElement("canvas");
  canvas.setAttribute("data-testid", "cv-canvas");
  stage.append(canvas);
  const readoutBox = document.createElement("div");
  readoutBox.className = "cv-readout";
  readoutBox.setAttribute("data-testid", "cv-readout");
  readoutBox.setAttribute("aria-live", "off");
  readoutBox.textContent = "point at the image: x, y and the pixel's values; wheel or + − to zoom, drag to pan";
  const meta = document.createElement("div");
  meta.className = "cv-meta";
  meta.setAttribute("data-testid", "cv-meta");
  const files = document.createElement("div");  // the capture's other files: depth, point cloud
  files.className = "cv-meta cv-files";
  files.setAttribute("data-testid", "cv-files");
  dlg.append(bar, stage, readoutBox, meta, files);
  document.body.append(dlg);
  el = { ...el, title, zoomText, png, stage, canvas, readout: readoutBox, meta, files, choose, sides, steps,
         frameText, replay };

  stage.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const r = stage.getBoundingClientRect();
    zoomBy(Math.pow(ZOOM_STEP, -Math.sign(ev.deltaY) * Math.min(4, Math.abs(ev.deltaY) / 100 || 1)),
           ev.clientX - r.left, ev.clientY - r.top);
  }, { passive: false });
  stage.addEventListener("pointerdown", (ev) => {
    if (ev.button !== 0) return;
    stage.setPointerCapture(ev.pointerId);
    state.drag = { x: ev.clientX, y: ev.clientY, tx: state.tx, ty: state.ty };
    stage.classList.add("dragging");
  });
  stage.addEventListener("pointermove", (ev) => {
    if (state.drag) {
      state.tx = state.drag.tx + ev.clientX - state.drag.x;
      state.ty = state.drag.ty + ev.clientY - state.drag.y;
      draw();
    }
    state.pointer = { x: ev.clientX, y: ev.clientY };
    readout();
  });
  const endDrag = () => { state.drag = null; stage.classList.remove("dragging"); };
  stage.addEventListener("pointerup", endDrag);
  stage.addEventListener("pointercancel", endDrag);
  stage.addEventListener("pointerleave", () => { if (!state.drag) { state.pointer = null; readout(); } });
  dlg.addEventListener("keydown", (ev) => {
    if (ev.key === "+" || ev.key === "=") { ev.preventDefault(); zoomBy(ZOOM_STEP); }
    else if (ev.key === "-") { ev.preventDefault(); zoomBy(1 / ZOOM_STEP); }
    else if (ev.key === "0") { ev.preventDefault(); fitView(); draw(); }
    else if (state.kind === "recording" && !ev.ctrlKey && !ev.metaKey && !ev.altKey) {
      const to = { ArrowLeft: state.index - 1, ArrowRight: state.index + 1, Home: 0, End: state.frames - 1 }[ev.key];
      if (to !== undefined) { ev.preventDefault(); showFrame(to); }
    }
  });
  dlg.addEventListener("close", () => {
    state.id = null;
    if (state.bitmap) { state.bitmap.close(); state.bitmap = null; }
    state.pixels = state.ypixels = null;
  });
  new ResizeObserver(() => { if (dlg.open) draw(); }).observe(stage);
}

// ---- geometry ---------------------------------------------------------------------------------------
function fitView() {
  const r = el.stage.getBoundingClientRect();
  if (!state.w || !r.width) return;
  state.zoom = Math.min(r.width / state.w, r.height / state.h);
  state.tx = (r.width - state.w * state.zoom) / 2;
  state.ty = (r.height - state.h * state.zoom) / 2;
}

function zoomTo(z, cx, cy) {
  const r = el.stage.getBoundingClientRect();
  if (cx === undefined) { cx = r.width / 2; cy = r.height / 2; }
  const fitZoom = Math.min(r.width / (state.w || 1), r.height / (state.h || 1));
  const nz = Math.max(Math.min(fitZoom, 1) / 4, Math.min(ZOOM_MAX, z));
  // The image point under (cx, cy) stays there.
  state.tx = cx - (cx - state.tx) * nz / state.zoom;
  state.ty = cy - (cy - state.ty) * nz / state.zoom;
  state.zoom = nz;
  draw();
  readout();
}
function zoomBy(f, cx, cy) { zoomTo(state.zoom * f, cx, cy); }

function draw() {
  const c = el.canvas;
  const r = el.stage.getBoundingClientRect();
  const dpr = window.devicePixelRatio || 1;
  const cw = Math.max(1, Math.round(r.width * dpr)), ch = Math.max(1, Math.round(r.height * dpr));
  if (c.width !== cw || c.height !== ch) { c.width = cw; c.height = ch; }
  const ctx = c.getContext("2d");
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, cw, ch);
  if (state.bitmap) {
    ctx.imageSmoothingEnabled = false;
    ctx.setTransform(dpr * state.zoom, 0, 0, dpr * state.zoom, dpr * state.tx, dpr * state.ty);
    ctx.drawImage(state.bitmap, 0, 0);
  }
  c.dataset.zoom = String(state.zoom);
  c.dataset.tx = String(state.tx);
  c.dataset.ty = String(state.ty);
  el.zoomText.textContent = Math.round(state.zoom * dpr * 100) + " %";
}

// The image pixel under the pointer, from the stored PNG's decoded values.
function readout() {
  const box = el.readout;
  if (!state.pointer || !state.pixels) { box.dataset.x = ""; box.dataset.y = ""; return; }
  const r = el.stage.getBoundingClientRect();
  const x = Math.floor((state.pointer.x - r.left - state.tx) / state.zoom);
  const y = Math.floor((state.pointer.y - r.top - state.ty) / state.zoom);
  if (x < 0 || y < 0 || x >= state.w || y >= state.h) {
    box.textContent = "outside the image (" + state.w + " × " + state.h + ")";
    box.dataset.x = ""; box.dataset.y = "";
    return;
  }
  const i = 4 * (y * state.w + x);
  const p = state.pixels;
  const info = state.kind === "recording" ? { color: state.color }
    : (state.meta && state.meta.images && state.meta.images[state.image]) || {};
  const values = info.color === "gray" ? { gray: p[i] } : { r: p[i], g: p[i + 1], b: p[i + 2] };
  if (state.ypixels) values.y = state.ypixels[i];
  box.textContent = "x " + x + " · y " + y + " · " +
    Object.entries(values).map(([k, v]) => k.toUpperCase() + " " + v).join(" ");
  box.dataset.x = String(x);
  box.dataset.y = String(y);
  box.dataset.values = JSON.stringify(values);
}

async function decode(url) {
  const resp = await fetch(url);
  if (!resp.ok) throw new Error("GET " + url + " → " + resp.status);
  const bitmap = await createImageBitmap(await resp.blob(),
                                         { colorSpaceConversion: "none", premultiplyAlpha: "none" });
  const off = document.createElement("canvas");
  off.width = bitmap.width;
  off.height = bitmap.height;
  const ctx = off.getContext("2d", { willReadFrequently: true });
  ctx.drawImage(bitmap, 0, 0);
  return { bitmap, pixels: ctx.getImageData(0, 0, bitmap.width, bitmap.height).data, headers: resp.headers };
}

async function show(name) {
  if (!state.id) return;
  const seq = ++state.loadSeq;
  const base = "/api/captures/" + encodeURIComponent(state.id) + "/";
  const info = (state.meta && state.meta.images && state.meta.images[name]) || {};
  for (const [n, b] of Object.entries(el.choices)) b.setAttribute("aria-pressed", n === name ? "true" : "false");
  el.canvas.dataset.loaded = "";
  try {
    const main = await decode(base + (info.file || name + ".png"));
    const y = info.y_file ? await decode(base + info.y_file) : null;
    if (seq !== state.loadSeq) { main.bitmap.close(); if (y) y.bitmap.close(); return; }
    const sameSize = state.w === main.bitmap.width && state.h === main.bitmap.height;
    if (state.bitmap) state.bitmap.close();
    if (y) y.bitmap.close();
    state.image = name;
    state.bitmap = main.bitmap;
    state.pixels = main.pixels;
    state.ypixels = y ? y.pixels : null;
    state.w = main.bitmap.width;
    state.h = main.bitmap.height;
    if (!sameSize) fitView();  // another image of the same size keeps the zoom and pan: compare them
    el.png.href = base + (info.file || name + ".png");
    el.png.setAttribute("download", state.id + "-" + name + ".png");
    draw();
    readout();
    el.canvas.dataset.image = name;
    el.canvas.dataset.loaded = name;
  } catch (e) {
    if (seq === state.loadSeq) showMessage("cannot show " + name + " of capture " + state.id + ": " + e.message, "error");
  }
}

// ---- a recording, frame by frame ---------------------------------------------------------------------
function setMode(kind) {
  state.kind = kind;
  const rec = kind === "recording";
  el.choose.hidden = rec;
  el.replay.hidden = rec;
  el.sides.hidden = !rec;
  el.steps.hidden = !rec;
  el.files.hidden = rec;
  el.files.replaceChildren();
  el.canvas.dataset.index = "";
  el.canvas.dataset.frames = "";
}

function showSteps() {
  const { index, frames } = state;
  el.frameText.textContent = frames ? "frame " + index + " / " + (frames - 1) : "no frames";
  el.frameText.dataset.index = String(index);
  el.stepButtons.first.disabled = el.stepButtons.prev.disabled = index <= 0;
  el.stepButtons.next.disabled = el.stepButtons.last.disabled = index >= frames - 1;
  for (const [n, b] of Object.entries(el.sides)) b.setAttribute("aria-pressed", n === state.image ? "true" : "false");
}

async function showFrame(index) {
  if (state.kind !== "recording" || !state.id || !state.frames) return;
  index = Math.max(0, Math.min(state.frames - 1, index));
  const seq = ++state.loadSeq;
  const id = state.id;
  const side = state.image === "right" ? "right" : "left";
  state.index = index;
  showSteps();
  el.canvas.dataset.loaded = "";
  const url = "/api/recordings/" + encodeURIComponent(id) + "/frames/" + index + "/" + side + ".png";
  try {
    const main = await decode(url);
    if (seq !== state.loadSeq) { main.bitmap.close(); return; }
    const sameSize = state.w === main.bitmap.width && state.h === main.bitmap.height;
    if (state.bitmap) state.bitmap.close();
    state.bitmap = main.bitmap;
    state.pixels = main.pixels;
    state.ypixels = null;
    state.color = main.headers.get("X-Color") === "gray" ? "gray" : "rgb";
    const frames = Number(main.headers.get("X-Frames"));
    if (frames > 0 && frames !== state.frames) { state.frames = frames; showSteps(); }
    state.w = main.bitmap.width;
    state.h = main.bitmap.height;
    if (!sameSize) fitView();  // stepping keeps the zoom and the pan
    el.png.href = url;
    el.png.setAttribute("download", id + "-" + side + "_" + String(index).padStart(6, "0") + ".png");
    draw();
    readout();
    el.canvas.dataset.image = side;
    el.canvas.dataset.index = String(index);
    el.canvas.dataset.frames = String(state.frames);
    el.canvas.dataset.loaded = side + ":" + index;
  } catch (e) {
    if (seq === state.loadSeq) {
      showMessage("cannot show frame " + index + " of recording " + id + ": " + e.message +
                  "; list the recordings again (it may have been deleted)", "error");
    }
  }
}

/** Open a finished recording in the viewer at frame ``index`` (0: the first). */
/** The viewer emptied for ``id`` in ``mode`` (capture or recording), built on first use. */
function reset(id, mode) {
  if (!dlg) build();
  setMode(mode);
  state.id = id;
  state.meta = null;
  state.w = state.h = 0;
  el.title.textContent = id;
  el.meta.textContent = "";
  el.canvas.dataset.loaded = "";
}

export async function openRecording(id, index) {
  reset(id, "recording");
  state.index = index || 0;
  state.frames = 0;
  state.image = "left";
  showSteps();
  if (!dlg.open) dlg.showModal();
  await action(null, async () => {
    const info = await api("GET", "/api/recordings/" + encodeURIComponent(id));
    if (state.id !== id) return;
    state.frames = info.frames || 0;
    el.meta.textContent = ["recording", info.frames + " frames", info.fps ? info.fps.toFixed(1) + " fps" : "",
                           info.created, info.source, "calibration " + (info.calibration_id || "none"),
                           info.error ? "damaged: " + info.error : ""].filter(Boolean).join(" · ");
    showSteps();
    await showFrame(state.index);
  });
}

export async function replayCapture(id, btn) {
  return action(btn, async () => {
    const res = await api("POST", "/api/virtual-camera", { capture: id });
    showMessage("Replaying capture " + id + " through the fabric: the views show the virtual camera now (frame "
                + res.frame + ").", "info");
    return res;
  });
}

// The capture's files besides the images above (the stereo core's disparity and confidence, the point
// cloud), each a download link; and why the cloud is missing when the capture says so.
function showFiles(id, files, meta) {
  const shown = new Set(["meta.json"]);
  for (const [name] of IMAGES) {
    const info = (meta.images && meta.images[name]) || {};
    shown.add(info.file || name + ".png");
    if (info.y_file) shown.add(info.y_file);
  }
  const links = files.filter((f) => !shown.has(f.name)).map((f) => {
    const a = document.createElement("a");
    a.href = "/api/captures/" + encodeURIComponent(id) + "/" + encodeURIComponent(f.name);
    a.setAttribute("download", id + "-" + f.name);
    a.setAttribute("data-testid", "cv-file");
    a.textContent = f.name;
    a.title = f.bytes + " bytes";
    return a;
  });
  const parts = links.length ? ["files: "] : [];
  links.forEach((a, i) => parts.push(...(i ? [" · ", a] : [a])));
  const why = meta.depth && (meta.depth.cloud_unavailable || meta.depth.unavailable);
  if (why) parts.push((links.length ? " · " : "") + "no point cloud: " + why);
  el.files.replaceChildren(...parts);
}

export async function openViewer(id, image) {
  reset(id, "capture");
  if (!dlg.open) dlg.showModal();
  await action(null, async () => {
    const info = await api("GET", "/api/captures/" + encodeURIComponent(id));
    if (state.id !== id) return;
    state.meta = info.meta || {};
    const m = state.meta;
    el.meta.textContent = ["frame " + info.frame, info.source, m.time_utc, "calibration " + (info.calibration_id || "none"),
                           info.error ? "damaged: " + info.error : ""].filter(Boolean).join(" · ");
    showFiles(id, info.files || [], m);
    await show(image || "rect_left");
  });
}
