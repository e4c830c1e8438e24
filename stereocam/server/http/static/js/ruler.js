// The ruler (issue 24, item 4): two points picked on the rectified left view, the side-by-side view's
// left half or the disparity view (thumbnail or enlarged), and the distance in metres between the two
// 3-D points there. GET /api/ruler computes it, from the disparity at each point and the calibration's
// Q, exactly as the depth readout does (the frame: the frozen one, else the one the disparity view shows).
//
// While the ruler is on, a click on one of those views places a point (and does not enlarge the view);
// a third click starts again. The points, the line and the label are drawn over every such view. The
// points' x and y are also fields (typed from the keyboard, Enter measures). Escape or Clear clears it.
// Only the left image: the disparity map is the left camera's, so the right one has no depth of its own.
import { $, api, ApiError, VIEW_INFO, signInNeeded } from "./core.js";
import { disparityScale, viewPixel } from "./depth.js";
import { frozenFrame } from "./freeze.js";

const SVG = "http://www.w3.org/2000/svg";
const VIEWS = VIEW_INFO.filter((v) => v.readout && v.name !== "rect_right").map((v) => v.name);
const WIDE = new Set(VIEW_INFO.filter((v) => v.renders === "hconcat").map((v) => v.name));
const ruler = { on: false, points: [], result: null, error: "" };
const overlays = {};  // view -> svg

function svgEl(tag, attrs) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, String(v));
  return e;
}

function fmt(m) { return m >= 10 ? m.toFixed(2) + " m" : m >= 1 ? m.toFixed(3) + " m" : (m * 100).toFixed(1) + " cm"; }

// The overlay covers the <img> exactly; with preserveAspectRatio meet it letterboxes as object-fit: contain.
function place(view) {
  const svg = overlays[view], img = $("view-" + view);
  if (!svg || !img) return;
  svg.style.left = img.offsetLeft + "px";
  svg.style.top = img.offsetTop + "px";
  svg.style.width = img.offsetWidth + "px";
  svg.style.height = img.offsetHeight + "px";
}

function draw() {
  const scale = disparityScale();
  for (const view of VIEWS) {
    const svg = overlays[view];
    if (!svg) continue;
    svg.replaceChildren();
    const show = ruler.points.length > 0 && scale;
    svg.toggleAttribute("hidden", !show);
    if (!show) continue;
    const [w, h] = scale.frame_size;
    const vw = WIDE.has(view) ? 2 * w : w;
    svg.setAttribute("viewBox", "0 0 " + vw + " " + h);
    place(view);
    // frame pixels per screen pixel: marks and text keep their size on a thumbnail
    const img = $("view-" + view);
    const k = Math.max(vw / Math.max(1, img.offsetWidth), h / Math.max(1, img.offsetHeight));
    svg.style.fontSize = (14 * k) + "px";
    const [a, b] = ruler.points;
    if (b) {
      svg.append(svgEl("line", { x1: a.x + .5, y1: a.y + .5, x2: b.x + .5, y2: b.y + .5, class: "ruler-line" }));
    }
    ruler.points.forEach((p, i) => {
      svg.append(svgEl("circle", { cx: p.x + .5, cy: p.y + .5, r: 5 * k, class: "ruler-point" }));
      const t = svgEl("text", { x: p.x + 7 * k, y: p.y - 6 * k, class: "ruler-mark" });
      t.textContent = String(i + 1);
      svg.append(t);
    });
    if (b && (ruler.result || ruler.error)) {
      const t = svgEl("text", { x: (a.x + b.x) / 2 + 6 * k, y: (a.y + b.y) / 2 - 6 * k,
                                class: "ruler-label" + (ruler.error ? " error" : "") });
      t.textContent = ruler.result ? fmt(ruler.result.distance_m) : "?";
      svg.append(t);
    }
  }
}

function showText() {
  const label = $("ruler-label");
  label.dataset.error = ruler.error ? "1" : "";
  if (ruler.error) { label.textContent = ruler.error; return; }
  const r = ruler.result;
  if (r) {
    const [p, q] = r.points;
    label.textContent = fmt(r.distance_m) + " between 1 (x " + p.x + ", y " + p.y + ", Z " + fmt(p.depth_m) +
      ") and 2 (x " + q.x + ", y " + q.y + ", Z " + fmt(q.depth_m) + ") · frame " + r.frame;
    label.dataset.distance = String(r.distance_m);
    label.dataset.frame = String(r.frame);
    return;
  }
  delete label.dataset.distance;
  delete label.dataset.frame;
  label.textContent = !ruler.on ? "" : ruler.points.length === 0
    ? "Click point 1 on " + VIEWS.join(", ").replace("sbs", "sbs (left half)") + ", or type x and y below."
    : ruler.points.length === 1 ? "Point 1 at x " + ruler.points[0].x + ", y " + ruler.points[0].y + ": click point 2." : "measuring…";
}

function fillFields() {
  const names = ["x0", "y0", "x1", "y1"];
  const values = ruler.points.flatMap((p) => [p.x, p.y]);
  names.forEach((n, i) => { $("ruler-" + n).value = values[i] === undefined ? "" : String(values[i]); });
}

function shownDisparityFrame() {
  const n = Number($("view-disparity") && $("view-disparity").dataset.frame);
  return $("view-disparity") && $("view-disparity").dataset.frame && Number.isInteger(n) && n >= 0 ? n : null;
}

let asked = 0;
async function measure() {
  const [a, b] = ruler.points;
  if (!a || !b) return;
  const mine = ++asked;
  ruler.result = null;
  ruler.error = "";
  showText();
  const frozen = frozenFrame();
  const base = "/api/ruler?x0=" + a.x + "&y0=" + a.y + "&x1=" + b.x + "&y1=" + b.y;
  const frame = frozen !== null ? frozen : shownDisparityFrame();
  let res = null;
  try {
    // live, the frame shown may have left the daemon's few recent ones: then the newest will do
    const live = frozen === null ? "&fallback=newest" : "";
    res = await api("GET", base + (frame !== null ? "&frame=" + frame + live : ""));
  } catch (e) {
    if (e instanceof ApiError && e.status === 401) await signInNeeded();
    if (mine !== asked) return;
    ruler.error = e instanceof ApiError ? (e.detail || e.message) : String(e);
  }
  if (mine !== asked) return;
  ruler.result = res;
  showText();
  draw();
}

function addPoint(p) {
  if (ruler.points.length >= 2) { ruler.points = []; ruler.result = null; ruler.error = ""; }
  ruler.points.push(p);
  fillFields();
  showText();
  draw();
  measure();
}

export function clearRuler() {
  asked++;
  ruler.points = [];
  ruler.result = null;
  ruler.error = "";
  fillFields();
  showText();
  draw();
}

function setOn(on) {
  ruler.on = on;
  $("btn-ruler").setAttribute("aria-pressed", on ? "true" : "false");
  $("ruler-box").hidden = !on;
  document.body.dataset.ruler = on ? "on" : "";
  for (const view of VIEWS) {
    const fig = $("view-" + view) && $("view-" + view).closest("figure");
    if (fig) fig.classList.toggle("ruler-on", on);
  }
  if (!on) clearRuler(); else showText();
  syncBar();
}

function syncBar() { $("live-tools").hidden = $("ruler-box").hidden && $("freeze-state").hidden; }

export function toggleRuler() { setOn(!ruler.on); }

function fromFields() {
  const scale = disparityScale();
  const [w, h] = scale ? scale.frame_size : [Infinity, Infinity];
  const v = ["x0", "y0", "x1", "y1"].map((n) => $("ruler-" + n).value.trim());
  const nums = v.map(Number);
  for (let i = 0; i < 4; i++) {
    const hi = i % 2 ? h : w;
    if (v[i] === "" || !Number.isInteger(nums[i]) || nums[i] < 0 || nums[i] >= hi) {
      ruler.error = "point " + (i < 2 ? 1 : 2) + ": " + ["x0", "y0", "x1", "y1"][i] + " must be a whole number from 0 to " + (hi - 1);
      ruler.result = null;
      showText();
      return;
    }
  }
  ruler.points = [{ x: nums[0], y: nums[1] }, { x: nums[2], y: nums[3] }];
  draw();
  measure();
}

export function initRuler() {
  for (const view of VIEWS) {
    const img = $("view-" + view);
    if (!img) continue;
    const svg = svgEl("svg", { class: "ruler-overlay", "data-testid": "ruler-" + view, id: "ruler-" + view,
                               preserveAspectRatio: "xMidYMid meet", "aria-hidden": "true" });
    svg.toggleAttribute("hidden", true);
    img.after(svg);
    overlays[view] = svg;
    img.addEventListener("click", (ev) => {
      if (!ruler.on) return;
      ev.stopPropagation();  // a click with the ruler on places a point; it does not enlarge the view
      const scale = disparityScale();
      if (!scale) return;
      const [w, h] = scale.frame_size;
      const at = viewPixel(img, ev.clientX, ev.clientY, WIDE.has(view) ? 2 * w : w, h);
      if (!at) return;
      if (at.x >= w) {
        ruler.error = "pick points on the left half: the disparity is the left image's";
        showText();
        return;
      }
      addPoint(at);
    });
    new ResizeObserver(() => draw()).observe(img);
  }
  $("btn-ruler").addEventListener("click", toggleRuler);
  $("ruler-clear").addEventListener("click", clearRuler);
  $("ruler-form").addEventListener("submit", (ev) => { ev.preventDefault(); fromFields(); });
  // Escape clears the ruler first (the next one shrinks the enlarged view, as ever).
  window.addEventListener("keydown", (ev) => {
    if (ev.key !== "Escape" || !ruler.on || !ruler.points.length || document.querySelector("dialog[open]")) return;
    ev.stopPropagation();
    clearRuler();
  }, true);
  // A frozen frame's points are measured again on that frame; unfrozen: on the live one.
  document.addEventListener("stereocam:freeze", () => { syncBar(); if (ruler.points.length === 2) measure(); });
}
