// Freeze (issue 24, item 4): the live views stop at one frame, and the depth readout and the ruler read
// that frame's disparity, not the newest.
//
// The daemon holds the frame: POST /api/freeze {"frame": N} pins frame N (the one the disparity view
// shows: it is among the disparity view's last frames the daemon keeps), and the readouts ask with
// frame=N. While frozen the page asks the socket for no views (the daemon encodes nothing for it); on
// unfreeze it releases the frame (DELETE /api/freeze/N) and asks for its views again. A frozen frame the
// daemon no longer holds (several tabs froze others since) is answered 410: the readouts say to freeze
// again. live.js reads isFrozen() and listens for "stereocam:freeze".
import { $, api, ApiError, showError, signInNeeded } from "./core.js";

const state = { frame: null, pending: false };

export function isFrozen() { return state.pending || state.frame !== null; }
export function frozenFrame() { return state.frame; }

function announce() {
  const button = $("btn-freeze");
  const on = isFrozen();
  button.setAttribute("aria-pressed", on ? "true" : "false");
  button.textContent = on ? "Unfreeze" : "Freeze";
  const badge = $("freeze-state");
  badge.hidden = !on;
  badge.textContent = state.frame !== null ? "frozen at frame " + state.frame : "freezing…";
  badge.dataset.frame = state.frame === null ? "" : String(state.frame);
  document.body.dataset.frozen = state.frame !== null ? String(state.frame) : "";
  document.dispatchEvent(new CustomEvent("stereocam:freeze", { detail: { frame: state.frame } }));
}

// The frame the disparity view shows, once a JPEG it was given has finished loading (live.js clears
// img.onload when it has: data-frame then names the frame on screen).
async function shownFrame() {
  const img = $("view-disparity");
  if (!img) return null;
  for (let i = 0; i < 120 && img.onload; i++) await new Promise((r) => requestAnimationFrame(r));
  const n = Number(img.dataset.frame);
  return img.dataset.frame && Number.isInteger(n) ? n : null;
}

async function freeze() {
  state.pending = true;
  announce();  // live.js stops showing new frames from here
  const shown = await shownFrame();
  try {
    const res = await api("POST", "/api/freeze", shown === null ? {} : { frame: shown });
    state.frame = res.frame;
  } catch (e) {
    if (e instanceof ApiError && e.status === 401) await signInNeeded();
    else showError("could not freeze: " + (e.detail || e.message) + " (try again)");
    state.frame = null;
  }
  state.pending = false;
  announce();
}

async function unfreeze() {
  const frame = state.frame;
  state.frame = null;
  state.pending = false;
  announce();
  if (frame === null) return;
  try {
    await api("DELETE", "/api/freeze/" + frame);
  } catch (e) {
    // 404: the daemon let it go already (newer freezes pushed it out); nothing is lost either way
    if (!(e instanceof ApiError && e.status === 404)) showError("unfreeze: " + (e.detail || e.message));
  }
}

export function toggleFreeze() {
  if (state.pending) return;
  if (state.frame !== null) unfreeze(); else freeze();
}

export function initFreeze() {
  $("btn-freeze").addEventListener("click", toggleFreeze);
  // A tab closed while frozen lets its frame go.
  window.addEventListener("pagehide", () => {
    if (state.frame !== null) fetch("/api/freeze/" + state.frame, { method: "DELETE", keepalive: true, credentials: "same-origin" });
  });
}
