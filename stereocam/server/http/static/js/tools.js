// The stereo tools on the live views (issue 24, item 4).
//
// - Epipolar check, on the side-by-side view (the registry's `hconcat` view): horizontal lines every
//   LINE_STEP px of the frame and the features GET /api/alignment matched, left point to right point,
//   with the figure "rows agree within M px median, P px 90th; N matches" refreshed about once a
//   second while it is on. Over WARN_MEDIAN_PX the figure turns orange and says the rig may need
//   recalibrating: rectified rows of a calibrated rig agree within a fraction of a pixel.
// - Exposure, on each raw view (the registry's `raw` views): a histogram under the view (gray and
//   R, G, B; GET /api/histogram) with the share of clipped pixels, and, as a second toggle, the
//   daemon's clipping mask over the view (red: 255 in some channel, blue: black).
// The toggles sit in a bar under each view (their clicks never enlarge it; digits still pick views).
// Nothing is asked of the daemon while every tool is off, while the page is hidden or waiting for
// the sign-in; a 401 brings the sign-in back.
import { $, api, ApiError, VIEW_INFO, signInNeeded, waitingForSignIn } from "./core.js";

const SVG = "http://www.w3.org/2000/svg";
const PERIOD_MS = 1000;
const LINE_STEP = 32;        // frame pixels between epipolar lines
const WARN_MEDIAN_PX = 1.0;  // over this median the rig may need recalibrating
const GOOD_DY_PX = 1.0;      // a match drawn green within this, orange beyond

const SBS = VIEW_INFO.filter((v) => v.renders === "hconcat").map((v) => v.name);
const RAW = VIEW_INFO.filter((v) => v.raw).map((v) => v.name);

function el(tag, cls, testid) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (testid) { e.setAttribute("data-testid", testid); e.id = testid; }
  return e;
}

function svgEl(tag, attrs) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, String(v));
  return e;
}

// The view's tools: a bar of toggles over the picture (top right, under the fullscreen button: it takes
// no room while they are off) and, under the picture, what they show (hidden while nothing is on: the
// default layout keeps its height). Clicks in either stay there (the figure would enlarge).
function toolBar(view) {
  const img = $("view-" + view);
  if (!img) return null;
  const fig = img.closest("figure");
  const bar = el("div", "view-tools", "tools-" + view);
  const out = el("div", "view-tools-out", "tools-out-" + view);
  out.hidden = true;
  for (const e of [bar, out]) {
    e.addEventListener("click", (ev) => ev.stopPropagation());
    e.addEventListener("keydown", (ev) => { if (ev.key === "Enter" || ev.key === " ") ev.stopPropagation(); });
  }
  fig.append(bar, out);
  return { fig, img, bar, out };
}

function syncOut(out) { out.hidden = ![...out.children].some((c) => !c.hidden); }

function toggle(bar, id, text, title) {
  const label = el("label", "check view-tool");
  const box = el("input", "", id);
  box.type = "checkbox";
  box.id = id;
  label.title = title;
  label.append(box, " " + text);
  bar.append(label);
  return box;
}

function pct(share) {
  const p = share * 100;
  return (p === 0 ? "0" : p < 0.1 ? "<0.1" : p.toFixed(1)) + "%";
}

// ---- epipolar lines and row misalignment ------------------------------------------------------------
const epi = [];  // {view, box, svg, figureText}

function drawAlignment(slot, res) {
  const w = res.width, h = res.height;
  const svg = slot.svg;
  svg.setAttribute("viewBox", "0 0 " + 2 * w + " " + h);
  svg.replaceChildren();
  const lines = svgEl("g", { class: "epi-lines" });
  for (let y = LINE_STEP / 2; y < h; y += LINE_STEP) {
    lines.append(svgEl("line", { x1: 0, y1: y, x2: 2 * w, y2: y }));
  }
  svg.append(lines);
  const matches = svgEl("g", { class: "epi-matches" });
  for (const [xl, yl, xr, yr] of res.matches || []) {
    const cls = Math.abs(yr - yl) <= GOOD_DY_PX ? "good" : "off";
    matches.append(svgEl("line", { x1: xl, y1: yl, x2: w + xr, y2: yr, class: cls }));
    matches.append(svgEl("circle", { cx: xl, cy: yl, r: 3, class: cls }));
    matches.append(svgEl("circle", { cx: w + xr, cy: yr, r: 3, class: cls }));
  }
  svg.append(matches);
  svg.dataset.frame = String(res.frame);
  svg.dataset.lines = String(lines.childElementCount);
  svg.dataset.matches = String((res.matches || []).length);
  svg.toggleAttribute("hidden", false);
}

function alignmentText(res) {
  const m = res.median_dy_px, p = res.p90_dy_px, n = res.matches_count;
  if (m > WARN_MEDIAN_PX) {
    return ["rows differ by " + m.toFixed(2) + " px median, " + p.toFixed(2) + " px 90th (" + n +
            " matches): the rig may have moved; recalibrate it", "warn"];
  }
  return ["rows agree within " + m.toFixed(2) + " px median, " + p.toFixed(2) + " px 90th; " + n + " matches", "ok"];
}

async function pollAlignment(slot) {
  if (!slot.box.checked) return;
  let res = null, text = "", cls = "muted";
  try {
    res = await api("GET", "/api/alignment");
    [text, cls] = alignmentText(res);
  } catch (e) {
    if (e instanceof ApiError && e.status === 401) { await signInNeeded(); slot.box.checked = false; }
    text = e instanceof ApiError && e.status === 422 ? "too few features to measure the rows: point the cameras at a textured, well-lit scene"
      : e instanceof ApiError && e.status === 503 ? "no signal: nothing to measure"
      : "alignment unavailable: " + (e.detail || e.message);
    cls = "muted";
  }
  if (!slot.box.checked) return;
  if (res) drawAlignment(slot, res); else slot.svg.toggleAttribute("hidden", true);
  slot.figure.textContent = text;
  slot.figure.className = "tool-figure " + cls;
  slot.figure.hidden = false;
  syncOut(slot.out);
  if (res) slot.figure.dataset.median = String(res.median_dy_px);
}

// ---- exposure: histograms and clipping ----------------------------------------------------------------
const expo = {};  // raw view -> {hist, clip, canvas, text, mask}

function drawHistogram(slot, h) {
  const c = slot.canvas;
  const ctx = c.getContext("2d");
  const W = c.width, H = c.height;
  ctx.clearRect(0, 0, W, H);
  ctx.fillStyle = "#111";
  ctx.fillRect(0, 0, W, H);
  const hist = h.histogram;
  let top = 1;
  for (const k of ["y", "r", "g", "b"]) for (let i = 1; i < 255; i++) top = Math.max(top, hist[k][i]);
  const y = (n) => H - Math.min(1, Math.sqrt(n / top)) * (H - 2);  // square root: the tails stay visible
  ctx.fillStyle = "rgba(200, 200, 200, 0.55)";
  for (let i = 0; i < 256; i++) {
    const x = i * W / 256;
    ctx.fillRect(x, y(hist.y[i]), W / 256 + 0.5, H - y(hist.y[i]));
  }
  for (const [k, colour] of [["r", "#e06c75"], ["g", "#98c379"], ["b", "#61afef"]]) {
    ctx.strokeStyle = colour;
    ctx.lineWidth = 1;
    ctx.beginPath();
    for (let i = 0; i < 256; i++) {
      const x = (i + 0.5) * W / 256;
      if (i === 0) ctx.moveTo(x, y(hist[k][i])); else ctx.lineTo(x, y(hist[k][i]));
    }
    ctx.stroke();
  }
  // The clipped ends, as bars at the edges: red at 255, blue at 0 (their height: their share, enlarged).
  ctx.fillStyle = "#ff3b30";
  ctx.fillRect(W - 3, H - Math.min(1, h.clipped_high * 20) * H, 3, H);
  ctx.fillStyle = "#3b7bff";
  ctx.fillRect(0, H - Math.min(1, h.clipped_low * 20) * H, 3, H);
  c.dataset.drawn = "1";
}

function exposureWanted() { return RAW.filter((v) => expo[v] && (expo[v].hist.checked || expo[v].clip.checked)); }

async function pollHistogram() {
  const wanted = exposureWanted();
  if (!wanted.length) return;
  const clip = wanted.some((v) => expo[v].clip.checked);
  const query = (wanted.length === 1 ? "view=" + wanted[0] + "&" : "") + "mask=" + (clip ? 1 : 0);
  let res = null, why = "";
  try {
    res = await api("GET", "/api/histogram?" + query);
  } catch (e) {
    if (e instanceof ApiError && e.status === 401) {
      await signInNeeded();
      for (const v of wanted) { expo[v].hist.checked = false; expo[v].clip.checked = false; }
    }
    why = e instanceof ApiError && e.status === 503 ? "no signal" : "histogram unavailable: " + (e.detail || e.message);
  }
  for (const v of wanted) {
    const slot = expo[v];
    const h = res && res.views[v];
    if (slot.hist.checked) {
      slot.canvas.hidden = false;
      slot.text.hidden = false;
      if (h) {
        drawHistogram(slot, h);
        slot.canvas.dataset.frame = String(res.frame);
        slot.text.textContent = "clipped: " + pct(h.clipped_high) + " at 255, " + pct(h.clipped_low) + " black";
        slot.text.className = "tool-figure " + (h.clipped_high > 0.01 || h.clipped_low > 0.01 ? "warn" : "ok");
      } else {
        slot.text.textContent = why;
        slot.text.className = "tool-figure muted";
      }
    }
    syncOut(slot.out);
    if (slot.clip.checked && h && h.mask_png) {
      slot.mask.src = h.mask_png;
      slot.mask.dataset.frame = String(res.frame);
      slot.mask.hidden = false;
    }
  }
}

// ---- the loops ------------------------------------------------------------------------------------------
let timer = null;
let running = false;

function anyOn() { return epi.some((s) => s.box.checked) || exposureWanted().length > 0; }

async function tick() {
  timer = null;
  if (running) return;
  if (!anyOn() || document.visibilityState !== "visible" || waitingForSignIn()) return;
  running = true;
  try {
    await Promise.all([...epi.map(pollAlignment), pollHistogram()]);
  } finally {
    running = false;
  }
  if (anyOn() && !timer) timer = setTimeout(tick, PERIOD_MS);
}

function kick() {
  if (timer) { clearTimeout(timer); timer = null; }
  tick();
}

export function initTools() {
  for (const view of SBS) {
    const t = toolBar(view);
    if (!t) continue;
    const svg = svgEl("svg", { class: "epi-overlay", id: "epi-" + view, "data-testid": "epi-" + view,
                               preserveAspectRatio: "xMidYMid meet", "aria-hidden": "true" });
    svg.toggleAttribute("hidden", true);
    t.img.after(svg);
    const box = toggle(t.bar, "epi-toggle-" + view, "epipolar lines",
                       "draw epipolar lines and the matched features; measure how well the rows agree");
    const figure = el("span", "tool-figure", "epi-figure-" + view);
    figure.hidden = true;
    figure.setAttribute("aria-live", "polite");
    t.out.append(figure);
    const slot = { view, box, svg, figure, out: t.out };
    epi.push(slot);
    box.addEventListener("change", () => {
      if (!box.checked) { svg.toggleAttribute("hidden", true); figure.hidden = true; svg.replaceChildren(); }
      else { figure.textContent = "measuring…"; figure.className = "tool-figure muted"; figure.hidden = false; }
      syncOut(t.out);
      kick();
    });
  }
  for (const view of RAW) {
    const t = toolBar(view);
    if (!t) continue;
    const mask = el("img", "clip-overlay", "clip-" + view);
    mask.alt = "";
    mask.hidden = true;
    t.img.after(mask);
    const hist = toggle(t.bar, "hist-toggle-" + view, "histogram", "the exposure histogram of this camera");
    const clip = toggle(t.bar, "clip-toggle-" + view, "clipping", "mark pixels at 255 (red) and black (blue)");
    const canvas = el("canvas", "histogram", "hist-" + view);
    canvas.width = 256;
    canvas.height = 56;
    canvas.hidden = true;
    canvas.setAttribute("role", "img");
    canvas.setAttribute("aria-label", "histogram of " + view);
    const text = el("span", "tool-figure", "hist-figure-" + view);
    text.hidden = true;
    t.out.append(canvas, text);
    expo[view] = { hist, clip, canvas, text, mask, out: t.out };
    hist.addEventListener("change", () => {
      if (!hist.checked) { canvas.hidden = true; text.hidden = true; delete canvas.dataset.drawn; }
      syncOut(t.out);
      kick();
    });
    clip.addEventListener("change", () => {
      if (!clip.checked) { mask.hidden = true; mask.removeAttribute("src"); }
      kick();
    });
  }
  document.addEventListener("visibilitychange", kick);
}
