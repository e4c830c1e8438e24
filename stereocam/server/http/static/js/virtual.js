// The virtual camera's upload and Verify (POST /api/virtual-camera, POST /api/verify).
import { $, ApiError, api, action, bust, fmt, loadImage, showInfo, showSuccess } from "./core.js";
import { fitQuery, uploadForm } from "./fit.js";
import { setSourceRadios } from "./source.js";

// ---- virtual camera and verify --------------------------------------------------
const UPLOAD = "POST /api/virtual-camera";  // the message key of an upload (see core.js, messages)
async function upload(ev) {
  ev.preventDefault();
  const btn = $("btn-upload");
  await action(btn, async () => {
    const form = uploadForm($);
    if (!form) {
      throw new ApiError("Choose a left and a right image, or one side-by-side image, then press Send.");
    }
    const res = await api("POST", "/api/virtual-camera" + fitQuery(), form);
    setSourceRadios(res && res.source ? res.source : "virtual");
    $("upload-info").textContent = "frame " + fmt(res.frame) + ", " + fmt(res.width) + "×" + fmt(res.height) +
                                   ", source " + fmt(res.source) +
                                   (res.fit && res.fit.mode !== "exact" ? "; " + res.fit.text : "");
    const box = $("upload-result");
    box.dataset.frame = String(res.frame);
    await Promise.all(["left", "right"].map((side) => loadImage($("vc-result-" + side),
      bust("/api/virtual-camera/result/" + side + ".png"))));
    box.hidden = false;
    showSuccess("Sent through the fabric (frame " + fmt(res.frame) + "): the views now show the virtual camera. " +
                "Press Verify to compare the fabric with the model.", UPLOAD);
  }, { key: UPLOAD, explain: {
    400: (e) => "The images could not be read: " + e.detail + ". Choose other files and send again.",
    413: (e) => "The images are too large for the daemon: " + e.detail + ".",
    // The daemon's "; upload a PNG, ... image" is API advice: the page says what to choose.
    415: (e) => "That image format is not taken: " + e.detail.replace(/; upload an? .* image$/, "") +
                ". Choose an 8-bit PNG, BMP, JPEG or TIFF image and send again.",
    // The API's hint names its parameter ("; or send fit=..."): the page names its chooser.
    422: (e) => "The images do not fit the fabric: " + e.detail.replace(/; or send fit=.*$/, "") +
                ". Choose crop, pad or scale under fit (Another size than the fabric's) and send again, " +
                "or resize them.",
    504: "The fabric returned nothing within 2 s, so the source is back to live. Try again; " +
         "if it keeps happening, see the daemon's log.",
  } });
}


function renderVerify(res) {
  const box = $("verify-result");
  const yes = !!res.identical;
  const strong = $("verify-identical");
  strong.textContent = yes ? "yes — identical" : "no — differs";
  strong.className = yes ? "ok" : "bad";
  box.dataset.identical = String(yes);
  const tbody = $("verify-table").tBodies[0];
  const frag = document.createDocumentFragment();
  const row = (name, c, cls) => {
    const tr = document.createElement("tr");
    if (cls) tr.className = cls;
    tr.setAttribute("data-testid", "verify-row-" + name);
    const psnr = c.psnr_db === null || c.psnr_db === undefined ? "∞" : fmt(c.psnr_db);
    const share = typeof c.share === "number" ? (c.share * 100).toFixed(3) + " %" : fmt(c.share);
    for (const cell of [name, fmt(c.differing), share, fmt(c.max_diff), psnr]) {
      const td = document.createElement("td");
      td.textContent = cell;
      tr.append(td);
    }
    frag.append(tr);
  };
  for (const [name, c] of Object.entries(res.channels || {})) row(name, c, c.differing ? "bad" : "");
  row("all", res, "total");
  tbody.replaceChildren(frag);
  const where = $("verify-where");
  const parts = [];
  for (const [cam, r] of Object.entries(res.regions || {})) {
    if (r) parts.push(cam + " camera: x " + r.x0 + "–" + r.x1 + ", y " + r.y0 + "–" + r.y1);
  }
  const first = res.first_difference;
  if (first) parts.unshift("first at (" + first.x + ", " + first.y + ")");
  where.textContent = parts.length ? "differences: " + parts.join("; ") : "";
  where.hidden = !parts.length;
  box.hidden = false;
  return loadImage($("verify-difference"), bust("/api/verify/difference.png"));
}

async function verify() {
  const btn = $("btn-verify");
  await action(btn, async () => {
    const res = await api("POST", "/api/verify");
    await renderVerify(res);
    if (res.identical) showSuccess("Verify: the fabric's output is identical to the model's.", "POST /api/verify");
    else showInfo("Verify: the fabric's output differs from the model's: see the table and the difference image.", "POST /api/verify");
  }, { explain: {
    409: "Verify needs a virtual-camera input first: upload a pair (Virtual camera panel), then press Verify.",
  } });
}


export function initVirtual() {
  $("upload-form").addEventListener("submit", upload);
  $("btn-verify").addEventListener("click", verify);
}
