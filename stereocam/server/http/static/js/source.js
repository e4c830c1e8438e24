// The live/virtual switch (PUT /api/source).
import { $, api, showError, showSuccess } from "./core.js";

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
    showSuccess(source === "live" ? "Source: the live cameras." : "Source: the virtual camera (its last input).",
                "PUT /api/source");
    return true;
  } catch (e) {
    sourceBusy = false;
    showError(e, { explain: {
      409: "The virtual camera has no input yet: upload a pair (Virtual camera panel), which switches to it. " +
           "The source stays live.",
      503: (x) => "The switch did not take the change: " + x.detail + ". The daemon tries again by itself.",
    } });
    setSourceRadios(currentSource);
    return false;
  }
}


// Switch to `source` ("live" | "virtual") as the radios do (keyboard shortcuts).
export function chooseSource(source) {
  const radio = $("source-" + source);
  if (!radio || radio.checked) return;
  radio.checked = true;
  radio.dispatchEvent(new Event("change", { bubbles: true }));
}

export function initSource() {
  for (const s of ["live", "virtual"]) {
    $("source-" + s).addEventListener("change", (ev) => { if (ev.target.checked) putSource(s); });
  }
}
