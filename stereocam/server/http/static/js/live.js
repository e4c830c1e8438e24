// The live views, over one WebSocket (see core.js).
import { $, VIEWS, WS_FPS, BACKOFF_MIN_MS, BACKOFF_MAX_MS, showError, fmt, signInNeeded,
         waitingForSignIn } from "./core.js";
import { initDepth } from "./depth.js";
import { isFrozen } from "./freeze.js";
import { shownViews, viewSettings } from "./views.js";

// ---- live views over one WebSocket ----------------------------------------------
const decoder = new TextDecoder("utf-8");
const live = {};  // view -> {img, url (current blob URL), frames, caption, got: [[t, bytes]], lat: [[t, ms]]}
for (const v of VIEWS) {
  live[v] = { img: $("view-" + v), url: null, caption: $("frame-" + v), frames: 0, got: [], lat: [] };
}

let ws = null;
let backoff = BACKOFF_MIN_MS;
let reconnectTimer = null;
let everConnected = false;

function setConn(text, cls) {
  const el = $("conn");
  el.textContent = text;
  el.className = "badge " + cls;
}

function showFallback(text) {
  const el = $("ws-fallback");
  if (text) { el.textContent = text; el.hidden = false; } else { el.textContent = ""; el.hidden = true; }
}

// ---- bandwidth and glass-to-glass latency (issue 24, item 4) -------------------------------------
// Bandwidth: the bytes of each view's messages as they arrive (header and JPEG), over the last
// NET_WINDOW_MS. Latency of a frame: its age when the daemon sent it (header age_s: the daemon's
// clock at send minus the capture time, one clock), plus half the socket's round trip (a {"ping"}
// every PING_MS, the median of the last few), plus the time from its arrival here to the first
// animation frame after the JPEG decoded (when it is on screen).
const NET_WINDOW_MS = 2000;
const PING_MS = 2000;
const rtts = [];
let pingTimer = null;

function rttMs() {
  if (!rtts.length) return null;
  const s = [...rtts].sort((a, b) => a - b);
  return s[Math.floor(s.length / 2)];
}

function fmtRate(bps) {
  if (bps >= 1e6) return (bps / 1e6).toFixed(bps >= 1e7 ? 0 : 1) + " MB/s";
  if (bps >= 1e3) return (bps / 1e3).toFixed(0) + " kB/s";
  return Math.round(bps) + " B/s";
}

function trim(list, now) { while (list.length && list[0][0] < now - NET_WINDOW_MS) list.shift(); }

function renderNet() {
  const now = performance.now();
  let total = 0;
  for (const v of VIEWS) {
    const slot = live[v];
    trim(slot.got, now);
    trim(slot.lat, now);
    const el = $("net-" + v);
    if (!el) continue;
    const bytes = slot.got.reduce((a, x) => a + x[1], 0);
    // bytes over the window, or over the time since the first frame in it when the view just started
    const span = slot.got.length > 1 ? Math.max(now - slot.got[0][0], 1000) : NET_WINDOW_MS;
    const bps = slot.got.length ? bytes * 1000 / span : 0;
    total += bps;
    const lat = slot.lat.length ? slot.lat.reduce((a, x) => a + x[1], 0) / slot.lat.length : null;
    if (!slot.got.length) { el.textContent = ""; el.title = ""; el.dataset.bps = ""; el.dataset.latencyMs = ""; continue; }
    el.textContent = fmtRate(bps) + (lat === null ? "" : " · " + Math.round(lat) + " ms");
    el.dataset.bps = String(Math.round(bps));
    el.dataset.latencyMs = lat === null ? "" : lat.toFixed(1);
    const rtt = rttMs();
    el.title = "received: " + fmtRate(bps) + " over the last " + NET_WINDOW_MS / 1000 + " s" +
      (lat === null ? "" : "; glass to glass " + Math.round(lat) + " ms: the frame's age as the daemon sent it" +
       (rtt === null ? "" : ", half the round trip (" + Math.round(rtt) + " ms)") + ", and decoding to the screen");
  }
  const text = total > 0 ? fmtRate(total) : "";
  const box = $("bw-total");
  if (box) {
    box.textContent = text ? "Received: " + text + " in all" : "";
    box.dataset.bps = String(Math.round(total));
  }
  const summary = $("bw-summary");
  if (summary) summary.textContent = text;
}
setInterval(renderNet, 1000);

function ping() {
  if (ws && ws.readyState === WebSocket.OPEN && !document.hidden) ws.send(JSON.stringify({ ping: performance.now() }));
}

function onFrame(buf) {
  if (!(buf instanceof ArrayBuffer) || buf.byteLength < 4) return;
  const arrived = performance.now();
  const hlen = new DataView(buf).getUint32(0, false);
  if (4 + hlen > buf.byteLength) return;
  let header;
  try { header = JSON.parse(decoder.decode(new Uint8Array(buf, 4, hlen))); } catch (e) { return; }
  const slot = live[header.view];
  if (!slot || isFrozen()) return;  // frozen: the views keep the frame they show
  slot.got.push([arrived, buf.byteLength]);
  const url = URL.createObjectURL(new Blob([new Uint8Array(buf, 4 + hlen)], { type: "image/jpeg" }));
  const previous = slot.url;
  slot.url = url;
  const img = slot.img;
  slot.frames += 1;
  const received = slot.frames;
  img.onload = () => {
    // data-frame names the frame actually on screen: set once the JPEG has decoded.
    if (previous) URL.revokeObjectURL(previous);
    img.onload = img.onerror = null;
    img.dataset.frame = String(header.frame);
    img.dataset.signal = String(header.signal !== false);  // false while it shows NO SIGNAL
    // The decoded size, read here because naturalWidth is 0 again while the next src loads.
    img.dataset.size = img.naturalWidth + "x" + img.naturalHeight;
    img.dataset.timestamp = String(header.timestamp);
    img.dataset.received = String(received);
    if (typeof header.age_s === "number") {
      requestAnimationFrame(() => {
        const shown = performance.now();
        const rtt = rttMs();
        slot.lat.push([shown, header.age_s * 1000 + (rtt === null ? 0 : rtt / 2) + (shown - arrived)]);
      });
    }
    if (slot.caption) slot.caption.textContent = "#" + header.frame;
    if (slot.caption) slot.caption.dataset.frame = String(header.frame);
  };
  img.onerror = () => {
    if (previous) URL.revokeObjectURL(previous);
    img.onload = img.onerror = null;
  };
  img.src = url;
}

// What the socket asks for (issue 24, item 3): each shown view at the size it is shown, times the
// device pixel ratio (the smallest of the daemon's stream scales that is at least that wide; one
// `scale` for the thumbnails that do with a reduced size, `full` for those that need the whole
// frame), nothing for a hidden view, and nothing while the page is hidden (a background tab costs
// the daemon nothing). When the CPU budget lowers a full-size view's rate, that view steps down to
// half size (never below: the old thumbnail) and says so on its caption, until the layout changes.
const SCALES = [0.25, 0.5, 1];
const BUDGET_FLOOR = 0.5;
let enlarged = null;
let frameSize = [752, 480];
const budgetCap = {};  // view -> the largest scale the CPU budget affords it, until the layout changes
const asked = {};      // view -> the scale last asked for
let lastMessage = "";

function neededScale(view) {
  const img = $("view-" + view);
  const fig = img && img.closest("figure");
  const base = frameSize[0] * (fig && fig.classList.contains("view-wide") ? 2 : 1);
  const want = img ? img.clientWidth * (window.devicePixelRatio || 1) : base;
  const fits = SCALES.find((s) => base * s >= want);
  return { scale: fits === undefined ? 1 : fits, base, want, capped: fits === undefined };
}

function showNote(view, text) {
  const el = $("note-" + view);
  if (!el) return;
  el.textContent = text;
  el.hidden = !text;
}

function subscribe() {
  // frozen (freeze.js): nothing, so the daemon encodes nothing for this page
  const views = document.hidden || isFrozen() ? [] : shownViews();
  const full = [];
  let thumb = SCALES[0];
  const own = {};  // view -> its chosen settings (views.js): sent as its own entry
  for (const v of views) {
    const need = neededScale(v);
    const mine = viewSettings(v);
    if (Object.keys(mine).length) own[v] = mine;
    if (mine.scale !== undefined) {  // a size the user chose: no automatic sizing, no step down
      asked[v] = mine.scale;
      showNote(v, "");
      continue;
    }
    let scale = v === enlarged ? 1 : need.scale;
    let why = need.capped && v === enlarged ? "" : (need.capped ? "the camera's full width" : "");
    if (v !== enlarged && budgetCap[v] !== undefined && scale > budgetCap[v]) {  // enlarged: full size
      scale = budgetCap[v];
      why = "CPU budget";
    }
    asked[v] = scale;
    if (scale === 1) full.push(v); else thumb = Math.max(thumb, scale);
    showNote(v, why ? "shown at " + Math.round(need.base * scale) + " px: " + why : "");
  }
  // the thumbnails share one scale: those asking less get the largest of them
  for (const v of views) if (asked[v] !== 1 && (own[v] || {}).scale === undefined) asked[v] = thumb;
  if (!ws || ws.readyState !== WebSocket.OPEN) return;
  const entries = views.map((v) => (own[v] ? { view: v, ...own[v] } : v));
  const message = JSON.stringify({ views: entries, fps: WS_FPS, scale: thumb, full: full });
  if (message === lastMessage) return;
  lastMessage = message;
  ws.send(message);
}

// A resize or a layout change re-asks (debounced: a window being dragged asks once it settles),
// and gives the CPU budget another chance at the sizes shown.
let resizeTimer = null;
function relayout() {
  clearTimeout(resizeTimer);
  resizeTimer = setTimeout(() => {
    for (const v of Object.keys(budgetCap)) delete budgetCap[v];
    subscribe();
  }, 250);
}
window.addEventListener("resize", relayout);
document.addEventListener("stereocam:views-layout", () => {
  if (enlarged && !shownViews().includes(enlarged)) enlarge(enlarged);
  relayout();
});
// Only a change of width re-asks: a note appearing on a caption changes the height, and must not
// undo the CPU budget's step down (it would go back and forth).
let viewsWidth = 0;
if (window.ResizeObserver) {
  new ResizeObserver((entries) => {
    const w = Math.round(entries[entries.length - 1].contentRect.width);
    if (w !== viewsWidth) { viewsWidth = w; relayout(); }
  }).observe($("views"));
}

function enlarge(view) {
  enlarged = enlarged === view ? null : view;
  for (const fig of document.querySelectorAll("#views figure.view")) {
    const on = fig.dataset.view === enlarged;
    fig.classList.toggle("view-enlarged", on);
    fig.setAttribute("aria-expanded", on ? "true" : "false");
  }
  if (enlarged) $("view-" + enlarged).closest("figure").scrollIntoView({ block: "nearest" });
  subscribe();
}

// Fullscreen (the Fullscreen API) on the enlarged view: its button, or F while a view has the focus.
// The view stays enlarged (full size from the daemon) while it fills the screen.
let fullscreenLeftAt = 0;
async function toggleFullscreen(fig) {
  if (document.fullscreenElement) { await document.exitFullscreen(); return; }
  if (enlarged !== fig.dataset.view) enlarge(fig.dataset.view);
  try {
    await fig.requestFullscreen({ navigationUI: "hide" });
  } catch (e) {
    showError("fullscreen: the browser refused it (" + e.message + ")");
  }
}
document.addEventListener("fullscreenchange", () => {
  const el = document.fullscreenElement;
  for (const fig of document.querySelectorAll("#views figure.view")) {
    const on = fig === el;
    fig.classList.toggle("view-fullscreen", on);
    const btn = fig.querySelector(".view-fs");
    if (btn) {
      btn.textContent = on ? "exit fullscreen" : "fullscreen";
      btn.setAttribute("aria-pressed", on ? "true" : "false");
    }
  }
  if (!el) fullscreenLeftAt = performance.now();
});

for (const fig of document.querySelectorAll("#views figure.view")) {
  fig.tabIndex = 0;
  fig.setAttribute("role", "button");
  fig.setAttribute("aria-expanded", "false");
  fig.title = "click: full size; click again: back to the thumbnail";
  const fs = document.createElement("button");
  fs.type = "button";
  fs.className = "view-fs";
  fs.textContent = "fullscreen";
  fs.title = "fill the screen with this view (Esc leaves)";
  fs.setAttribute("aria-pressed", "false");
  fs.setAttribute("data-testid", "fullscreen-" + fig.dataset.view);
  fs.addEventListener("click", (ev) => { ev.stopPropagation(); toggleFullscreen(fig); });
  fs.addEventListener("keydown", (ev) => ev.stopPropagation());
  fig.append(fs);
  fig.addEventListener("click", (ev) => {
    if (document.fullscreenElement === fig) return;  // a click in fullscreen does not shrink the view
    if (ev.target.closest && ev.target.closest(".disparity-legend")) return;
    enlarge(fig.dataset.view);
  });
  fig.addEventListener("keydown", (ev) => {
    if (ev.key === "Enter" || ev.key === " ") { ev.preventDefault(); enlarge(fig.dataset.view); }
    if ((ev.key === "f" || ev.key === "F") && !ev.ctrlKey && !ev.metaKey && !ev.altKey) {
      ev.preventDefault();
      toggleFullscreen(fig);
    }
  });
}
document.addEventListener("keydown", (ev) => {
  // Esc in fullscreen leaves fullscreen only (the browser's doing); the next Esc shrinks the view.
  if (ev.key !== "Escape" || !enlarged || document.fullscreenElement) return;
  if (performance.now() - fullscreenLeftAt < 300) return;
  if (document.querySelector("dialog[open]")) return;  // the capture viewer handles its own Esc
  enlarge(enlarged);
});
initDepth();
document.addEventListener("visibilitychange", subscribe);
document.addEventListener("stereocam:freeze", subscribe);

// Each view's delivered and planned rate, and why it is below what the page asked (/api/status).
export function renderViewRates(st) {
  if (Array.isArray(st.frame_size) && st.frame_size.length === 2) frameSize = st.frame_size;
  let lowered = false;
  for (const e of (st.encoders || [])) {
    // a full-size view the CPU budget slowed down steps down to half size (see subscribe)
    if (e.scale === 1 && asked[e.view] === 1 && e.view !== enlarged && e.planned_fps < e.target_fps &&
        viewSettings(e.view).scale === undefined &&
        (e.limited_by || "").startsWith("CPU budget") && budgetCap[e.view] === undefined) {
      budgetCap[e.view] = BUDGET_FLOOR;
      lowered = true;
    }
  }
  if (lowered) subscribe();
  const byView = {};
  for (const e of (st.encoders || [])) {
    const best = byView[e.view];
    if (!best || e.planned_fps > best.planned_fps) byView[e.view] = e;
  }
  for (const v of VIEWS) {
    const el = $("rate-" + v);
    if (!el) continue;
    const e = byView[v];
    if (!e) { el.textContent = ""; el.title = ""; el.className = "view-rate"; continue; }
    const limited = e.limited_by && e.planned_fps < e.target_fps;
    el.textContent = fmt(e.delivered_fps) + " / " + fmt(e.target_fps) + " fps" + (limited ? " ▾" : "");
    el.title = limited ? "lowered to " + fmt(e.planned_fps) + " fps: " + e.limited_by
      : (e.limited_by ? "at most " + fmt(e.target_fps) + " fps: " + e.limited_by : "");
    el.className = "view-rate" + (limited ? " limited" : "");
    el.dataset.planned = String(e.planned_fps);
    el.dataset.limitedBy = e.limited_by || "";
  }
}

export function connect() {
  reconnectTimer = null;
  if (waitingForSignIn()) return;  // the views say they wait for the sign-in; nothing retries
  const proto = window.location.protocol === "https:" ? "wss:" : "ws:";
  const sock = new WebSocket(proto + "//" + window.location.host + "/ws");
  sock.binaryType = "arraybuffer";
  ws = sock;
  setConn(everConnected ? "reconnecting…" : "connecting…", "badge-warn");
  sock.onopen = () => {
    everConnected = true;
    lastMessage = "";
    backoff = BACKOFF_MIN_MS;
    setConn("live", "badge-ok");
    showFallback("");
    subscribe();
    rtts.length = 0;
    ping();
    clearInterval(pingTimer);
    pingTimer = setInterval(ping, PING_MS);
  };
  sock.onmessage = (ev) => {
    if (typeof ev.data === "string") {
      // The daemon may send a JSON text message (e.g. {"error": ...}).
      try {
        const msg = JSON.parse(ev.data);
        if (msg && typeof msg.pong === "number") {
          rtts.push(performance.now() - msg.pong);
          if (rtts.length > 5) rtts.shift();
          return;
        }
        if (msg && msg.error) showError("live view: " + msg.error);
      } catch (e) { /* not JSON: ignore */ }
      return;
    }
    onFrame(ev.data);
  };
  sock.onclose = async (ev) => {
    if (ws !== sock) return;
    ws = null;
    clearInterval(pingTimer);
    // Refused for want of the token (a 401 on the upgrade, or the daemon's token changed): the page
    // shows the sign-in state and the views wait for it instead of reconnecting over and over.
    if (!everConnected || ev.code !== 1000) {
      if (await signInNeeded()) return;
    }
    const wait = backoff;
    backoff = Math.min(BACKOFF_MAX_MS, backoff * 2);
    setConn("disconnected", "badge-bad");
    showFallback("Live view disconnected" + (ev.reason ? " (" + ev.reason + ")" : "") +
                 ": reconnecting in " + (wait / 1000).toFixed(1) + " s. The last frames stay on screen.");
    reconnectTimer = setTimeout(connect, wait);
  };
  sock.onerror = () => { /* onclose follows and schedules the reconnect */ };
}


export function closeLive() { if (ws) ws.close(); }
document.addEventListener("stereocam:signin", () => {
  clearTimeout(reconnectTimer);
  reconnectTimer = null;
  showFallback("");
  const sock = ws;
  ws = null;
  if (sock) sock.close();
});
