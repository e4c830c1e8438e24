// Readouts on the live views and the disparity view's colour scale (issue 13, item 5).
//
// - Point readout: over rect_left, rect_right, sbs and disparity, the pointer's pixel in full-resolution
//   rectified coordinates (exact whatever the view's displayed size: see viewPixel), that pixel's values
//   in both rectified images, and over rect_left, sbs's left half and disparity the disparity and the
//   depth in metres from the active calibration's Q matrix (GET /api/point computes them from the very
//   disparity map the view shows; the page never reads depth from JPEG colours).
// - Legend: the disparity view's JET colours 0..128 px (GET /api/disparity gives the daemon's exact
//   colour table), labelled in pixels and, when a calibration is known, in metres (Z = f B / d).
//   While the views are frozen (freeze.js) the readout reads the frozen frame (frame=N), whatever the
//   daemon has made since; live, the frame the disparity view shows (the newest when it is gone).
import { $, api, ApiError, VIEW_INFO, waitingForSignIn } from "./core.js";
import { frozenFrame } from "./freeze.js";

const READOUT_VIEWS = VIEW_INFO.filter((v) => v.readout).map((v) => v.name);  // the registry says which
const LEGEND_TICKS = [0, 16, 32, 64, 96, 128];
let scaleInfo = null;  // GET /api/disparity
export function disparityScale() { return scaleInfo; }

// The full-resolution pixel under (clientX, clientY) of an <img> showing a view of fullW x fullH pixels,
// whatever its displayed size: the <img> is laid out with object-fit: contain (letterboxed to its
// natural aspect), and the JPEG it shows may be a thumbnail (its natural size a fraction of the view's).
// Pixel (u, v) covers [u, u+1) x [v, v+1) of the image's area. Null outside the picture.
export function viewPixel(img, clientX, clientY, fullW, fullH) {
  const r = img.getBoundingClientRect();
  const nw = img.naturalWidth || fullW, nh = img.naturalHeight || fullH;
  const s = Math.min(r.width / nw, r.height / nh);
  if (!(s > 0)) return null;
  const cw = nw * s, ch = nh * s;
  const left = r.left + (r.width - cw) / 2, top = r.top + (r.height - ch) / 2;
  const x = Math.floor((clientX - left) / cw * fullW);
  const y = Math.floor((clientY - top) / ch * fullH);
  if (x < 0 || y < 0 || x >= fullW || y >= fullH) return null;
  return { x, y };
}

function fmtDepth(m) {
  if (m === null || m === undefined) return "—";
  return m >= 10 ? m.toFixed(1) + " m" : m.toFixed(3) + " m";
}

function rgbText(p) { return p.r === p.g && p.g === p.b ? "gray " + p.r : p.r + " " + p.g + " " + p.b; }

// ---- point readout ----------------------------------------------------------------------------------
function attachReadout(view) {
  const img = $("view-" + view);
  if (!img) return;
  const fig = img.closest("figure");
  const box = document.createElement("div");
  box.className = "view-readout";
  box.id = "readout-" + view;
  box.setAttribute("data-testid", "readout-" + view);
  box.setAttribute("aria-live", "off");
  box.hidden = true;
  fig.append(box);
  let want = null;      // {x, y, side} the pointer is on
  let inFlight = false;
  let shownKey = "";

  async function ask() {
    if (inFlight || !want) return;
    const target = want;
    const key = keyOf(target);
    if (key === shownKey) return;
    inFlight = true;
    try {
      const frozen = frozenFrame();
      const frame = frozen !== null ? String(frozen) : $("view-disparity").dataset.frame;
      const q = "/api/point?x=" + target.x + "&y=" + target.y;
      // live, the frame shown may have left the daemon's few recent ones: then the newest will do
      const live = frozen === null ? "&fallback=newest" : "";
      const p = await api("GET", q + (frame ? "&frame=" + frame + live : ""));
      if (want) show(p, target);
      shownKey = key;
    } catch (e) {
      box.textContent = e instanceof ApiError ? e.message.replace(/^GET \S+ → /, "") : String(e);
      box.dataset.error = "1";
      shownKey = "";
    } finally {
      inFlight = false;
    }
    if (want && keyOf(want) !== shownKey) ask();
  }

  function keyOf(t) { return t.x + "," + t.y + "," + t.side + "," + frozenFrame(); }
  document.addEventListener("stereocam:freeze", () => { shownKey = ""; ask(); });

  function show(p, target) {
    const px = target.side === "right" ? p.rect_right : p.rect_left;
    const parts = [(target.side === "right" ? "right " : "") + "x " + p.x + " y " + p.y];
    if (view !== "disparity") parts.push(rgbText(px) + (px.y !== px.r || px.r !== px.g ? " · Y " + px.y : ""));
    if (target.side === "left") {
      parts.push(p.disparity_px === null ? "no disparity" : "d " + p.disparity_px.toFixed(2) + " px");
      if (p.disparity_px !== null) {
        parts.push(p.depth_m !== null ? "Z " + fmtDepth(p.depth_m)
          : (p.disparity_px === 0 ? "Z ∞" : "Z —"));
      }
    }
    box.textContent = parts.join(" · ");
    box.title = p.depth_unavailable || ("frame " + p.frame + (p.calibration_id ? ", calibration " + p.calibration_id : ""));
    box.dataset.error = "";
    box.dataset.x = String(p.x);
    box.dataset.y = String(p.y);
    box.dataset.side = target.side;
    box.dataset.frame = String(p.frame);
    box.dataset.values = JSON.stringify(px);
    box.dataset.disparity = p.disparity_px === null ? "" : String(p.disparity_px);
    box.dataset.depth = p.depth_m === null ? "" : String(p.depth_m);
    box.hidden = false;
  }

  img.addEventListener("pointermove", (ev) => {
    if (!scaleInfo) return;
    const [w, h] = scaleInfo.frame_size;
    const fullW = view === "sbs" ? 2 * w : w;
    const at = viewPixel(img, ev.clientX, ev.clientY, fullW, h);
    if (!at) { want = null; box.hidden = true; return; }
    let side = view === "rect_right" ? "right" : "left";
    if (view === "sbs" && at.x >= w) { side = "right"; at.x -= w; }
    want = { x: at.x, y: at.y, side };
    box.dataset.pointer = at.x + "," + at.y + "," + side;
    box.dataset.client = ev.clientX + "," + ev.clientY;
    ask();
  });
  img.addEventListener("pointerleave", () => { want = null; shownKey = ""; box.hidden = true; });
}

// ---- the disparity legend ---------------------------------------------------------------------------
function drawLegend() {
  const holder = $("disparity-legend");
  if (!holder || !scaleInfo) return;
  const bar = holder.querySelector("canvas");
  const ctx = bar.getContext("2d");
  const colors = scaleInfo.colors;
  const n = scaleInfo.num_disparities;
  bar.width = 256;
  bar.height = 1;
  for (let i = 0; i < 256; i++) {
    // The view's level of disparity d is round(d * 255 / n): column i shows d = i * n / 256.
    const level = Math.min(255, Math.round((i + 0.5) * n / 256 * 255 / n));
    ctx.fillStyle = colors[level];
    ctx.fillRect(i, 0, 1, 1);
  }
  const fb = scaleInfo.focal_px && scaleInfo.baseline_m ? scaleInfo.focal_px * scaleInfo.baseline_m : null;
  const labels = holder.querySelector(".legend-labels");
  labels.replaceChildren();
  for (const d of LEGEND_TICKS) {
    const t = document.createElement("span");
    t.className = "legend-tick";
    t.style.left = (100 * d / n) + "%";
    t.dataset.disparity = String(d);
    const z = fb === null ? null : (d === 0 ? Infinity : fb / d);
    t.dataset.depth = z === null ? "" : String(z);
    t.textContent = d + (z === null ? "" : " · " + (z === Infinity ? "∞" : (z >= 10 ? z.toFixed(0) : z.toFixed(2))));
    labels.append(t);
  }
  thinTicks(labels);
  holder.querySelector(".legend-unit").textContent = "disparity px" + (fb === null ? "" : " · depth m");
  holder.title = fb === null ? "no calibration: depth unknown"
    : "Z = f·B/d with f = " + scaleInfo.focal_px.toFixed(1) + " px, B = " + (scaleInfo.baseline_m * 1000).toFixed(1)
      + " mm (calibration " + scaleInfo.calibration_id + ")";
  holder.dataset.calibration = scaleInfo.calibration_id || "";
  holder.dataset.ready = "1";
}

// On a narrow view the labels would run into each other: hide those that would touch the last one
// shown (the first and the last always stay, as they give the scale's ends). Called again at each resize.
function thinTicks(labels) {
  const ticks = [...labels.querySelectorAll(".legend-tick")];
  for (const t of ticks) t.hidden = false;
  if (ticks.length < 3 || !labels.offsetWidth) return;
  const GAP = 6;
  const last = ticks[ticks.length - 1].getBoundingClientRect();
  let prev = ticks[0].getBoundingClientRect();
  for (const t of ticks.slice(1, -1)) {
    const r = t.getBoundingClientRect();
    if (r.left < prev.right + GAP || r.right > last.left - GAP) t.hidden = true;
    else prev = r;
  }
}

function makeLegend() {
  const img = $("view-disparity");
  if (!img || $("disparity-legend")) return;
  const holder = document.createElement("div");
  holder.className = "disparity-legend";
  holder.id = "disparity-legend";
  holder.setAttribute("data-testid", "disparity-legend");
  const bar = document.createElement("canvas");
  bar.setAttribute("aria-label", "colour scale of the disparity view, 0 to 128 pixels");
  const labels = document.createElement("div");
  labels.className = "legend-labels";
  const unit = document.createElement("div");
  unit.className = "legend-unit";
  holder.append(bar, labels, unit);
  img.after(holder);
  new ResizeObserver(() => thinTicks(labels)).observe(labels);
}

export async function refreshDisparityScale() {
  if (waitingForSignIn()) return;
  try {
    const info = await api("GET", "/api/disparity");
    const changed = !scaleInfo || info.calibration_id !== scaleInfo.calibration_id;
    scaleInfo = info;
    if (changed) drawLegend();
  } catch (e) {
    /* the next refresh tries again; the readouts stay off until it answers */
  }
}

export function initDepth() {
  makeLegend();
  for (const v of READOUT_VIEWS) attachReadout(v);
  refreshDisparityScale();
  // A calibration applied from the panel changes the depth labels: follow it while the page is shown.
  setInterval(() => { if (!document.hidden) refreshDisparityScale(); }, 5000);
}
