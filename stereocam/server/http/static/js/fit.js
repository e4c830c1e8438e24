// Fit on upload (issue 13, item 2): the user chooses how a pair of another size than the
// fabric's frame is made to fit, and sees what the fabric will get before sending it.
//
// Contract: stereocam/server/API.md, "Fit" and POST /api/virtual-camera/preview.
//
// init(ctx) — call once after the DOM is ready. ctx gives:
//   ctx.api(method, path, body)  core.js's api(): JSON in and out, throws ApiError on non-2xx
//   ctx.showError, ctx.showInfo  core.js's (unused here: a preview's problem is said in #fit-info,
//                                beside the chooser, not as a page message)
//   ctx.$(id)                    document.getElementById
//   (the preview is fetched here, a PNG, not JSON; the access token goes as the page's cookie)
// Returns { fit, fitQuery }: fit() is the chosen mode ("exact" | "crop" | "pad" | "scale"),
// fitQuery() the "?fit=<mode>" to append to POST /api/virtual-camera ("" for exact). The same
// two functions are exported for modules that import this one, and uploadForm($), the chosen files
// as the FormData both the preview and the upload send.
//
// Wiring the upload (stereocam/server/http/static/js/virtual.js, upload()):
//   import { fitQuery, uploadForm } from "./fit.js";
//   const form = uploadForm($);  // null: nothing usable chosen
//   const res = await api("POST", "/api/virtual-camera" + fitQuery(), form);
//   ... and show res.fit.text (what was done) in #upload-info when res.fit && res.fit.mode !== "exact".
//
// HTML (inside <form id="upload-form">, before the submit button; the file inputs
// #upload-left, #upload-right, #upload-sbs are the upload form's own):
//
//   <fieldset id="fit-panel" data-testid="fit-panel" class="fit">
//     <legend>Another size than the fabric's</legend>
//     <label>fit
//       <select id="upload-fit" data-testid="upload-fit" name="fit">
//         <option value="exact" selected>exact: refuse it</option>
//         <option value="crop">crop: the centre, cut to the frame</option>
//         <option value="pad">pad: centred on black</option>
//         <option value="scale">scale: resized, aspect kept, letterboxed</option>
//       </select></label>
//     <button type="button" id="btn-fit-preview" data-testid="btn-fit-preview">Preview</button>
//     <p id="fit-info" data-testid="fit-info" class="muted" aria-live="polite"></p>
//     <figure id="fit-figure" data-testid="fit-figure" hidden>
//       <img id="fit-preview" data-testid="fit-preview" alt="what the fabric will get: left | right">
//       <figcaption>what the fabric will get (left | right)</figcaption>
//     </figure>
//   </fieldset>
//
// Test hooks: #fit-figure's data-mode, data-from ("707x481"), data-to ("752x480") describe the
// preview shown; #fit-info holds the daemon's text of what the fit does.

const MODES = ["exact", "crop", "pad", "scale"];
let ctx = null;
let previewUrl = null;
let seq = 0;

export function fit() {
  const sel = ctx && ctx.$("upload-fit");
  const value = sel ? sel.value : "exact";
  return MODES.includes(value) ? value : "exact";
}

export function fitQuery() {
  const mode = fit();
  return mode === "exact" ? "" : "?fit=" + encodeURIComponent(mode);
}

// The upload form's files as a FormData, or null when neither a pair nor an sbs image is chosen:
// what the preview here and the upload (virtual.js) send. $ is document.getElementById.
export function uploadForm($) {
  const file = (id) => ($(id) && $(id).files && $(id).files[0]) || null;
  const l = file("upload-left"), r = file("upload-right"), s = file("upload-sbs");
  const form = new FormData();
  if (l && r) {
    form.append("left", l, l.name);
    form.append("right", r, r.name);
  } else if (s && !l && !r) {
    form.append("sbs", s, s.name);
  } else {
    return null;
  }
  return form;
}

function clearPreview(text) {
  const figure = ctx.$("fit-figure"), img = ctx.$("fit-preview");
  if (figure) {
    figure.hidden = true;
    delete figure.dataset.mode;
    delete figure.dataset.from;
    delete figure.dataset.to;
  }
  if (img) img.removeAttribute("src");
  if (previewUrl) URL.revokeObjectURL(previewUrl);
  previewUrl = null;
  const info = ctx.$("fit-info");
  if (info) {
    info.textContent = text || "";
    info.classList.remove("bad");
    delete info.dataset.problem;
  }
}

// Why the preview failed, in the page's words (what to click), in #fit-info (class "bad").
export function previewProblem(status, why, mode) {
  // The API's hint names the parameter ("; or send fit=..."); the page names the chooser.
  const plain = String(why || "").replace(/; or send fit=.*$/, "");
  if (status === 0) return "Preview: the daemon did not answer. Check that stereocam is running, then press Preview.";
  if (status === 422 && mode === "exact") return plain + ": choose crop, pad or scale under fit to make it fit.";
  return "Preview: " + plain + ".";
}

function showProblem(status, why) {
  const info = ctx.$("fit-info");
  if (!info) return;
  info.textContent = previewProblem(status, why, fit());
  info.classList.add("bad");
  info.dataset.problem = String(status);
}

// POST the chosen files to /api/virtual-camera/preview and show the PNG it answers.
async function preview(explicit) {
  const form = uploadForm(ctx.$);
  if (!form) {
    clearPreview(explicit ? "choose a left and a right image, or one side-by-side image" : "");
    return;
  }
  const mine = ++seq;
  const path = "/api/virtual-camera/preview" + "?fit=" + encodeURIComponent(fit());
  let resp;
  try {
    resp = await fetch(path, { method: "POST", body: form });
  } catch (e) {
    if (mine === seq) {
      clearPreview("");
      showProblem(0, "");
    }
    return;
  }
  if (mine !== seq) return;  // a newer preview was asked for meanwhile
  if (!resp.ok) {
    let why = resp.statusText;
    try { why = (await resp.json()).error || why; } catch (e) { /* not JSON */ }
    clearPreview("");
    // Said beside the chooser, not as a page message: it is an answer to the files just chosen
    // (asked again at each change), and the next choice replaces it.
    showProblem(resp.status, why);
    return;
  }
  let described = null;
  try { described = JSON.parse(resp.headers.get("X-Fit") || "null"); } catch (e) { described = null; }
  const blob = await resp.blob();
  if (mine !== seq) return;
  if (previewUrl) URL.revokeObjectURL(previewUrl);
  previewUrl = URL.createObjectURL(blob);
  const img = ctx.$("fit-preview"), figure = ctx.$("fit-figure");
  img.src = previewUrl;
  if (described) {
    figure.dataset.mode = described.mode;
    figure.dataset.from = described.from.join("x");
    figure.dataset.to = described.to.join("x");
    ctx.$("fit-info").textContent = described.mode === "exact"
      ? "already " + described.to.join("×") + ": sent as it is"
      : described.from.join("×") + " → " + described.to.join("×") + ": " + described.text;
  }
  figure.hidden = false;
}

export function init(c) {
  ctx = c;
  const $ = ctx.$;
  const sel = $("upload-fit");
  if (!sel) return { fit: fit, fitQuery: fitQuery };
  sel.addEventListener("change", () => preview(false));
  for (const id of ["upload-left", "upload-right", "upload-sbs"]) {
    const input = $(id);
    if (input) input.addEventListener("change", () => preview(false));
  }
  const btn = $("btn-fit-preview");
  if (btn) {
    btn.addEventListener("click", async () => {
      btn.disabled = true;
      try { await preview(true); } finally { btn.disabled = false; }
    });
  }
  return { fit: fit, fitQuery: fitQuery };
}
