// The live/virtual switch (PUT /api/source).
import { $, api, showError } from "./core.js";

let currentSource = null;
let sourceBusy = false;

export function setSourceRadios(source) {
  currentSource = source;
  if (sourceBusy) return;
  for (const s of ["live", "virtual"]) $("source-" + s).checked = source === s;
}

// ---- source switch --------------------------------------------------------------
async function putSource(source) {
  sourceBusy = true;
  try {
    const r = await api("PUT", "/api/source", { source: source });
    sourceBusy = false;
    setSourceRadios(r && r.source ? r.source : source);
    return true;
  } catch (e) {
    sourceBusy = false;
    showError(e.message);
    setSourceRadios(currentSource);
    return false;
  }
}


export function initSource() {
  for (const s of ["live", "virtual"]) {
    $("source-" + s).addEventListener("change", (ev) => { if (ev.target.checked) putSource(s); });
  }
}
