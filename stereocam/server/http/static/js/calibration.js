// The calibration panel.
import { $, ApiError, api, action, bust, clearMessages, fmt, keyBelongsTo, loadImage, showError, showSuccess } from "./core.js";

// ---- calibration panel (issue 4) ---------------------------------------------------
// While the panel is open and "show corners" is ticked, GET /api/calibration/corners is
// polled (one request at a time) and the corners are drawn over the raw views, on the very
// frame they were found in: the overlay holds that frame's image
// (GET /api/calibration/corners/{frame}/{side}.jpg) under the corners, so the raw views show
// the detection frames (a few a second) with their corners, never live frames with the corners
// of an older pose. Each overlay's data-frame is the frame it shows. Pairs, coverage, compute,
// figures and apply go through the /api/calibration/* endpoints.
const SVG_NS = "http://www.w3.org/2000/svg";
const CORNER_PAUSE_MS = 300;  // a detection costs tens of ms of the board's CPU
let cornersRunning = false;
let cornersFailing = false;
let calibSession = null;
let calibCandidate = null;

function svgEl(name, attrs) {
  const el = document.createElementNS(SVG_NS, name);
  for (const [k, v] of Object.entries(attrs || {})) el.setAttribute(k, String(v));
  return el;
}

function setViewBox(svg, size) {
  if (Array.isArray(size) && size.length === 2) svg.setAttribute("viewBox", "0 0 " + size[0] + " " + size[1]);
}

// The frame's image, decoded before it replaces the overlay's (no flash of an empty overlay).
async function frameImage(frame, side) {
  const fig = $("corners-" + side).closest("figure");
  const scale = fig && fig.classList.contains("view-enlarged") ? 1 : 0.5;
  const url = "/api/calibration/corners/" + frame + "/" + side + ".jpg?scale=" + scale;
  const img = new Image();
  img.src = url;
  await img.decode().catch(() => { throw new ApiError("the frame " + frame + " is no longer kept: trying the next one"); });
  return url;
}

function drawCorners(side, points, size, frame, imageUrl) {
  const svg = $("corners-" + side);
  setViewBox(svg, size);
  const frag = document.createDocumentFragment();
  const shown = Array.isArray(points) && points.length && imageUrl;
  if (shown) {
    frag.append(svgEl("image", { href: imageUrl, x: 0, y: 0, width: size[0], height: size[1],
                                 preserveAspectRatio: "none", class: "corners-frame" }));
    const label = svgEl("text", { x: 8, y: size[1] - 10, class: "corners-label" });
    label.textContent = "frame #" + frame + " (corners found)";
    frag.append(label);
  }
  if (shown) {
    frag.append(svgEl("polyline", { points: points.map((p) => p[0] + "," + p[1]).join(" "), class: "found" }));
    frag.append(svgEl("circle", { cx: points[0][0], cy: points[0][1], r: 6, class: "found" }));
    for (const p of points) frag.append(svgEl("circle", { cx: p[0], cy: p[1], r: 2.5, class: "found" }));
  }
  svg.replaceChildren(frag);
  svg.dataset.corners = String(shown ? points.length : 0);
  svg.dataset.frame = shown ? String(frame) : "";
  svg.classList.toggle("corners-on", !!shown);
}

function cornersWanted() { return $("calib").open && $("calib-live").checked; }

async function cornersLoop() {
  if (cornersRunning) return;
  cornersRunning = true;
  const state = $("calib-live-state");
  try {
    while (cornersWanted()) {
      try {
        const res = await api("GET", "/api/calibration/corners");
        cornersFailing = false;
        if (!cornersWanted()) break;
        const urls = await Promise.all(["left", "right"].map((side) =>
          (res[side] ? frameImage(res.frame, side) : Promise.resolve(null))));
        if (!cornersWanted()) break;
        drawCorners("left", res.left, res.image_size, res.frame, urls[0]);
        drawCorners("right", res.right, res.image_size, res.frame, urls[1]);
        const where = res.found ? "board " + res.pattern + " found in both views" :
          (res.left ? "found in the left view only" : res.right ? "found in the right view only" :
           "board " + res.pattern + " not found");
        state.textContent = where + " (frame #" + res.frame + ", " + fmt(res.ms) + " ms)";
        state.className = "calib-live-state" + (res.found ? " ok" : "");
        state.dataset.found = String(!!res.found);
        state.dataset.frame = String(res.frame);
      } catch (e) {
        // No frame from the cameras (503) is a state that ends by itself: said in the panel as a
        // warning until the corners come back, not as a page error.
        const waiting = e.status === 503;
        state.textContent = waiting ? "no frame from the cameras: waiting for the signal (Status panel); " +
                                      "the corners come back by themselves" : e.message;
        state.className = "calib-live-state " + (waiting ? "warn" : "bad");
        state.dataset.found = "false";
        for (const side of ["left", "right"]) drawCorners(side, null, null);
        // A frame replaced before its image came is normal (the next poll shows a newer one).
        if (!cornersFailing && e.status !== null && !waiting) showError(e);
        cornersFailing = true;
        await new Promise((r) => setTimeout(r, 1000));
      }
      await new Promise((r) => setTimeout(r, CORNER_PAUSE_MS));
    }
  } finally {
    cornersRunning = false;
    for (const side of ["left", "right"]) drawCorners(side, null, null);
    clearMessages("GET /api/calibration/corners", "error");
    if (!cornersWanted()) { state.textContent = "—"; state.className = "calib-live-state"; }
  }
}

function renderCoverage(session) {
  const size = session.image_size;
  for (const side of ["left", "right"]) {
    const svg = $("calib-coverage-" + side);
    setViewBox(svg, size);
    const frag = document.createDocumentFragment();
    for (const pair of session.pairs) {
      const pts = pair.corners && pair.corners[side];
      if (!Array.isArray(pts) || pts.length < 4) continue;
      frag.append(svgEl("polygon", { points: hull(pts).map((p) => p[0] + "," + p[1]).join(" ") }));
    }
    svg.replaceChildren(frag);
    const share = session.coverage ? session.coverage[side] : 0;
    const el = $("calib-coverage-" + side + "-share");
    el.textContent = Math.round(100 * (share || 0)) + " %";
    el.dataset.share = String(share || 0);
  }
}

// Convex hull (monotone chain) of [x, y] points: the board's outline as the corners show it.
function hull(points) {
  const p = points.slice().sort((a, b) => a[0] - b[0] || a[1] - b[1]);
  const cross = (o, a, b) => (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
  const lower = [], upper = [];
  for (const q of p) {
    while (lower.length >= 2 && cross(lower[lower.length - 2], lower[lower.length - 1], q) <= 0) lower.pop();
    lower.push(q);
  }
  for (const q of p.slice().reverse()) {
    while (upper.length >= 2 && cross(upper[upper.length - 2], upper[upper.length - 1], q) <= 0) upper.pop();
    upper.push(q);
  }
  return lower.slice(0, -1).concat(upper.slice(0, -1));
}

// "#n": the pair's place in the stored list (oldest first), the same number everywhere.
function pairLabel(id) {
  const i = calibSession ? calibSession.pairs.findIndex((p) => p.id === id) : -1;
  return i < 0 ? "(deleted)" : "#" + (i + 1);
}

function renderSession(session) {
  calibSession = session;
  const st = session.settings || {};
  const focused = document.activeElement;
  if (focused !== $("calib-pattern")) $("calib-pattern").value = st.pattern || "";
  if (focused !== $("calib-square")) $("calib-square").value = st.square_mm === undefined ? "" : String(st.square_mm);
  if (focused !== $("calib-alpha")) $("calib-alpha").value = st.alpha === undefined ? "" : String(st.alpha);
  const count = $("calib-count");
  count.textContent = String(session.count);
  count.dataset.count = String(session.count);
  $("calib-folder").textContent = session.folder ? "in " + session.folder : "";
  renderCoverage(session);
  const list = $("calib-pairs");
  const frag = document.createDocumentFragment();
  session.pairs.forEach((pair, i) => {
    const li = document.createElement("li");
    li.setAttribute("data-testid", "calib-pair");
    li.dataset.id = pair.id;
    if (calibCandidate && calibCandidate.worst_pair === pair.id) {
      li.className = "worst";
      li.title = "the largest row error in the computed calibration";
    }
    const info = document.createElement("div");
    info.className = "cap-info";
    const name = document.createElement("code");
    name.textContent = "#" + (i + 1) + " " + pair.id;
    const meta = document.createElement("small");
    meta.textContent = [pair.pattern, pair.frame !== undefined ? "frame " + pair.frame : "", pair.error || ""]
      .filter(Boolean).join(" · ");
    info.append(name, meta);
    const del = document.createElement("button");
    del.type = "button";
    del.className = "danger";
    del.textContent = "delete";
    del.setAttribute("data-testid", "calib-pair-delete");
    del.addEventListener("click", () => action(del, async () => {
      await api("DELETE", "/api/calibration/pairs/" + encodeURIComponent(pair.id));
      await refreshSession();
    }));
    li.append(info, del);
    frag.append(li);
  });
  list.replaceChildren(frag);
  $("btn-calib-clear").disabled = !session.count;
  if (calibCandidate) renderPairTable(calibCandidate);
  const progress = session.progress || {};
  if (progress.state === "running" && !computeWatching) watchCompute();
}

async function refreshSession() { renderSession(await api("GET", "/api/calibration/session")); }

async function putCalibSettings(fields) {
  try {
    renderSession(await api("PUT", "/api/calibration/session", fields));
  } catch (e) {
    showError(e, { explain: { 400: (x) => "That calibration setting was not taken: " + x.detail + "." } });
    if (calibSession) renderSession(calibSession);  // back to the settings in use
  }
}

function fixed(v, digits) { return typeof v === "number" ? v.toFixed(digits) : "—"; }

function renderCandidate(cand) {
  calibCandidate = cand;
  const r = cand.report;
  const box = $("calib-result");
  const dl = $("calib-figures");
  const rows = [
    ["pairs", r.pairs_used + " used, " + r.pairs_rejected + " rejected"],
    ["rms", fixed(r.rms, 3) + " px reprojection (RMS)"],
    ["row_error", fixed(r.row_error_mean, 3) + " px mean, " + fixed(r.row_error_max, 3) + " px max"],
    ["rows", r.rows_needed + " of " + r.lb_rows + " line-buffer rows" + (cand.fits ? "" : " — does NOT fit")],
    ["baseline", fixed(r.baseline_m * 1000, 2) + " mm"],
    ["left", "fx " + fixed(r.left.fx, 1) + " fy " + fixed(r.left.fy, 1) + " cx " + fixed(r.left.cx, 1) + " cy " + fixed(r.left.cy, 1)],
    ["right", "fx " + fixed(r.right.fx, 1) + " fy " + fixed(r.right.fy, 1) + " cx " + fixed(r.right.cx, 1) + " cy " + fixed(r.right.cy, 1)],
    ["id", cand.id],
  ];
  const frag = document.createDocumentFragment();
  for (const [key, value] of rows) {
    const dt = document.createElement("dt");
    dt.textContent = key.replace("_", " ");
    const dd = document.createElement("dd");
    dd.textContent = value;
    dd.setAttribute("data-testid", "calib-figure-" + key);
    if (key === "rows" && !cand.fits) dd.className = "bad";
    frag.append(dt, dd);
  }
  dl.replaceChildren(frag);

  renderPairTable(cand);
  const select = $("calib-preview-pair");
  if (cand.worst_pair && [...select.options].some((o) => o.value === cand.worst_pair)) select.value = cand.worst_pair;
  $("btn-calib-apply").disabled = !cand.fits;
  $("btn-calib-apply").title = cand.fits ? "" : "this calibration needs more line-buffer rows than the core has";
  box.dataset.id = cand.id;
  box.hidden = false;
  return showPreview();
}

function renderPairTable(cand) {
  const r = cand.report;
  // Bars: each pair's row error, mean (solid) and max (light), on one scale: the worst max.
  const scale = Math.max(1e-9, ...r.pairs.filter((p) => p.used).map((p) => p.row_error_max || 0));
  const tbody = $("calib-pair-table").tBodies[0];
  const tf = document.createDocumentFragment();
  const select = $("calib-preview-pair");
  const chosen = select.value;
  const options = document.createDocumentFragment();
  for (const p of r.pairs) {
    const label = pairLabel(p.id);
    const gone = label === "(deleted)";
    const tr = document.createElement("tr");
    tr.setAttribute("data-testid", "calib-pair-row");
    const cells = p.used ?
      [label, fixed(p.rms, 3), fixed(p.row_error_mean, 3) + " / " + fixed(p.row_error_max, 3)] :
      [label, "rejected", p.reason];
    for (const c of cells) {
      const td = document.createElement("td");
      td.textContent = c;
      tr.append(td);
    }
    const barCell = document.createElement("td");
    barCell.className = "bar-cell";
    if (p.used) {
      const track = document.createElement("div");
      track.className = "bar-track";
      track.setAttribute("data-testid", "calib-pair-bar");
      track.title = "row error " + fixed(p.row_error_mean, 3) + " px mean, " + fixed(p.row_error_max, 3) + " px max";
      const max = document.createElement("div");
      max.className = "bar bar-max";
      max.style.width = (100 * (p.row_error_max || 0) / scale).toFixed(1) + "%";
      const mean = document.createElement("div");
      mean.className = "bar bar-mean";
      mean.style.width = (100 * (p.row_error_mean || 0) / scale).toFixed(1) + "%";
      track.append(max, mean);
      barCell.append(track);
    } else {
      tr.className = "bad";
    }
    tr.append(barCell);
    const dropCell = document.createElement("td");
    dropCell.className = "drop-cell";
    if (!gone) {
      const drop = document.createElement("button");
      drop.type = "button";
      drop.className = "danger drop";
      drop.textContent = "×";
      drop.title = "delete this pair (then compute again)";
      drop.setAttribute("aria-label", "delete pair " + label);
      drop.setAttribute("data-testid", "calib-pair-row-delete");
      drop.addEventListener("click", () => action(drop, async () => {
        await api("DELETE", "/api/calibration/pairs/" + encodeURIComponent(p.id));
        await refreshSession();
      }));
      dropCell.append(drop);
    }
    tr.append(dropCell);
    if (p.id === cand.worst_pair) tr.classList.add("worst");
    tr.title = p.id || p.name;
    tf.append(tr);
    if (p.used && !gone) {
      const opt = document.createElement("option");
      opt.value = p.id;
      opt.textContent = label + (p.id === cand.worst_pair ? " (largest row error)" : "");
      options.append(opt);
    }
  }
  tbody.replaceChildren(tf);
  select.replaceChildren(options);
  if ([...select.options].some((o) => o.value === chosen)) select.value = chosen;
}

function showPreview() {
  const pair = $("calib-preview-pair").value;
  if (!pair) return Promise.resolve();
  const url = bust("/api/calibration/candidate/rectified.png?pair=" + encodeURIComponent(pair));
  $("calib-rectified-link").href = url;
  return loadImage($("calib-rectified"), url);
}

// Progress of a compute, whichever tab started it; when it is done the candidate is shown.
let computeWatching = false;
async function watchCompute() {
  if (computeWatching) return;
  computeWatching = true;
  const bar = $("calib-progress");
  const text = $("calib-progress-text");
  bar.hidden = false;
  bar.removeAttribute("value");
  try {
    for (;;) {
      let p;
      try { p = await api("GET", "/api/calibration/compute"); } catch (e) { p = { state: "unknown" }; }
      if (p.state === "running") {
        if (p.total) {
          bar.max = p.total;
          bar.value = p.done;
          text.textContent = p.stage + " " + p.done + " / " + p.total;
        } else {
          text.textContent = "computing…";
        }
      } else {
        if (p.state === "failed") text.textContent = "failed: " + p.error;
        if (p.state === "done") await loadCandidate();
        return;
      }
      await new Promise((r) => setTimeout(r, 250));
    }
  } finally {
    computeWatching = false;
    bar.hidden = true;
  }
}

async function loadCandidate() {
  let cand;
  try {
    cand = await api("GET", "/api/calibration/candidate");
  } catch (e) {
    if (e instanceof ApiError && e.status === 404) return;  // none computed yet
    throw e;
  }
  if (!calibCandidate || calibCandidate.id !== cand.id || calibCandidate.computed_at !== cand.computed_at) {
    $("calib-progress-text").textContent = "computed from " + cand.report.pairs_used + " pairs";
    await renderCandidate(cand);
  }
}

async function computeCalibration() {
  const btn = $("btn-calib-compute");
  await action(btn, async () => {
    $("calib-progress-text").textContent = "computing…";
    const watching = watchCompute();
    try {
      const cand = await api("POST", "/api/calibration/compute");
      $("calib-progress-text").textContent = "computed from " + cand.report.pairs_used + " pairs";
      await renderCandidate(cand);
      await refreshSession();
    } catch (e) {
      $("calib-progress-text").textContent = "";
      throw e;
    } finally {
      await watching;
    }
  }, { explain: {
    409: "A calibration is being computed already (perhaps from another tab): its result shows here when it is done.",
    422: (e) => "Calibration not computed: " + e.detail + ".",
  } });
}

export function initCalibration() {
  const details = $("calib");
  details.addEventListener("toggle", () => {
    if (details.open) {
      // Only ask for the candidate when the session says there is one (no 404 at each opening).
      action(null, async () => { await refreshSession(); if (calibSession && calibSession.candidate) await loadCandidate(); });
      cornersLoop();
    }
  });
  // Space or C captures a pair while the panel is open: the person holding the board may be
  // far from the mouse (a wireless keyboard or presenter remote sends these).
  document.addEventListener("keydown", (ev) => {
    if (!details.open || ev.repeat || ev.ctrlKey || ev.metaKey || ev.altKey || keyBelongsTo(ev.target, ev.key)) return;
    if (ev.key === " " || ev.key === "c" || ev.key === "C") {
      ev.preventDefault();
      const btn = $("btn-calib-pair");
      if (!btn.disabled) btn.click();
    }
  });
  $("calib-live").addEventListener("change", () => cornersLoop());
  $("calib-pattern").addEventListener("change", (ev) => putCalibSettings({ pattern: ev.target.value.trim() }));
  const numberSetting = (id, key, what) => $(id).addEventListener("change", (ev) => {
    const text = ev.target.value.trim();
    if (text === "" || !Number.isFinite(Number(text))) {
      showError("Give the " + what + " as a number; the previous value stays.");
      if (calibSession) renderSession(calibSession);
      return;
    }
    putCalibSettings({ [key]: Number(text) });
  });
  numberSetting("calib-square", "square_mm", "square size in millimetres");
  numberSetting("calib-alpha", "alpha", "alpha (0 to 1)");
  $("btn-calib-pair").addEventListener("click", (ev) => action(ev.currentTarget, async () => {
    const res = await api("POST", "/api/calibration/pairs");
    renderSession(res);
    showSuccess("Pair " + res.count + " stored." + (res.count < 5 ? " Move the board and store " + (5 - res.count) +
                " more (at least 5 to compute)." : " Compute when the coverage looks even."), "POST /api/calibration/pairs");
  }, { explain: {
    409: (e) => "Pair not stored: " + e.detail + ".",
    422: (e) => "Pair not stored: " + e.detail + ".",
    503: "Pair not stored: no frame from the cameras. Check the signal (Status panel), then try again.",
  } }));
  $("btn-calib-clear").addEventListener("click", (ev) => action(ev.currentTarget, async () => {
    if (!window.confirm("Delete every stored calibration pair?")) return;
    await api("DELETE", "/api/calibration/pairs");
    await refreshSession();
  }, { explain: { 409: "The pairs are in use by a running compute: delete them when it has finished." } }));
  $("btn-calib-compute").addEventListener("click", computeCalibration);
  $("calib-preview-pair").addEventListener("change", () => action(null, showPreview));
  // 318 px is too small to judge rows: a click shows the preview at its own size (one image pixel
  // a screen pixel), scrolled inside its frame; another click fits it again. A middle click or
  // ctrl-click still opens it in a tab.
  $("calib-rectified-link").addEventListener("click", (ev) => {
    if (ev.button !== 0 || ev.ctrlKey || ev.metaKey || ev.shiftKey) return;
    ev.preventDefault();
    const fig = $("calib-rectified-figure");
    const zoomed = fig.classList.toggle("zoomed");
    fig.dataset.zoomed = String(zoomed);
    $("calib-rectified-hint").textContent = zoomed ? "full size (scroll it sideways): click to fit it again"
                                                   : "click it to see it at full size";
  });
  $("btn-calib-apply").addEventListener("click", (ev) => action(ev.currentTarget, async () => {
    if (!calibCandidate) throw new ApiError("Compute a calibration first, then apply it.");
    const res = await api("POST", "/api/calibration/apply", { id: calibCandidate.id });
    $("calib-result").dataset.applied = res.id;
    showSuccess("Calibration " + res.id + " is now programmed in the core and saved to " + res.file +
                " (the next start uses it too).", "POST /api/calibration/apply");
  }, { explain: {
    409: "The calibration was computed again since this page showed it: review the new figures, then apply.",
    422: (e) => "The core cannot run this calibration: " + e.detail + ". Nothing changed.",
  } }));
}
