// Shared by every panel: the page's parameters, the access token, messages, the HTTP API
// and formatting.
//
// Contract: server/API.md. All live views come over ONE WebSocket (/ws): browsers
// allow about 6 connections per host, so seven MJPEG <img> streams would starve the
// API calls. Each binary message is
//   [4-byte big-endian header length][UTF-8 JSON {view, frame, timestamp}][JPEG bytes]
// and becomes a blob URL on that view's <img>; the previous blob URL is revoked once
// the new one has loaded. Each <img> carries data-frame / data-timestamp of the frame
// it shows (tests read them).
//
// Access token: when the daemon has `access_token` set, open the page as
// /?token=SECRET once. The token is stored in localStorage ("stereocam.token") and
// sent as "Authorization: Bearer SECRET" on POST/PUT/DELETE and as the stereocam_token
// cookie on everything else; /?token= (empty) forgets it.
//
// Errors: every failed API call shows the daemon's {"error": ...} text in #messages;
// nothing is swallowed.

export const VIEWS = ["raw_left", "raw_right", "rect_left", "rect_right", "sbs", "anaglyph", "disparity"];
const TOKEN_KEY = "stereocam.token";
export const params = new URLSearchParams(window.location.search);
export const WS_FPS = clampNumber(params.get("fps"), 1, 60, 15);
export const THUMB_SCALE = 0.5;  // of each view's size, one of the daemon's stream scales
export const STATUS_PERIOD_MS = 1000;
export const BACKOFF_MIN_MS = 500;
export const BACKOFF_MAX_MS = 10000;

export const $ = (id) => document.getElementById(id);

export function clampNumber(text, lo, hi, fallback) {
  const n = Number(text);
  if (text === null || text === "" || !Number.isFinite(n)) return fallback;
  return Math.min(hi, Math.max(lo, n));
}

// ---- access token ---------------------------------------------------------------
function readToken() {
  if (params.has("token")) {
    const t = params.get("token");
    try {
      if (t) localStorage.setItem(TOKEN_KEY, t); else localStorage.removeItem(TOKEN_KEY);
    } catch (e) { /* storage disabled: the query parameter still works for this page */ }
    return t || "";
  }
  try { return localStorage.getItem(TOKEN_KEY) || ""; } catch (e) { return ""; }
}
export const TOKEN = readToken();
// Streams, snapshots and the WebSocket cannot carry a header: with `protect: all` the daemon
// reads the token from this cookie (same site only, so a page of another origin never sends it).
document.cookie = "stereocam_token=" + (TOKEN ? encodeURIComponent(TOKEN) + "; max-age=31536000"
                                              : "; max-age=0") + "; path=/; SameSite=Strict";

// ---- messages -------------------------------------------------------------------
let messageSeq = 0;
export function showMessage(text, kind) {
  const box = $("messages");
  const item = document.createElement("div");
  item.className = "msg msg-" + (kind || "error");
  item.setAttribute("data-testid", kind === "info" ? "message-info" : "message-error");
  item.id = "message-" + (++messageSeq);
  const span = document.createElement("span");
  span.textContent = text;
  const close = document.createElement("button");
  close.type = "button";
  close.className = "msg-close";
  close.setAttribute("aria-label", "dismiss");
  close.textContent = "×";
  close.addEventListener("click", () => item.remove());
  item.append(span, close);
  box.append(item);
  while (box.children.length > 5) box.firstElementChild.remove();
  if (kind === "info") setTimeout(() => item.remove(), 4000);
}
export function showError(text) { showMessage(text, "error"); }

// ---- HTTP API -------------------------------------------------------------------
export class ApiError extends Error {}

// fetch + JSON; any non-2xx becomes ApiError with the daemon's "error" text.
export async function api(method, path, body) {
  const init = { method: method, headers: {} };
  if (method !== "GET" && TOKEN) init.headers["Authorization"] = "Bearer " + TOKEN;
  if (body instanceof FormData) {
    init.body = body;
  } else if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  let resp;
  try {
    resp = await fetch(path, init);
  } catch (e) {
    throw new ApiError(method + " " + path + ": the daemon is unreachable (" + e.message + ")");
  }
  const text = await resp.text();
  let data = null;
  if (text) {
    try { data = JSON.parse(text); } catch (e) { data = null; }
  }
  if (!resp.ok) {
    const why = data && typeof data.error === "string" ? data.error : (text.trim().slice(0, 200) || resp.statusText);
    throw new ApiError(method + " " + path + " → " + resp.status + ": " + why);
  }
  return data;
}

// Run an async UI action with its button disabled; errors go to #messages.
export async function action(button, fn) {
  if (button) button.disabled = true;
  try {
    return await fn();
  } catch (e) {
    showError(e instanceof ApiError ? e.message : "unexpected error: " + e);
    return undefined;
  } finally {
    if (button) button.disabled = false;
  }
}

export function bust(url) { return url + (url.includes("?") ? "&" : "?") + "t=" + Date.now(); }

export function fmt(v) {
  if (v === null || v === undefined) return "—";
  if (typeof v === "number") return Number.isInteger(v) ? String(v) : v.toFixed(2);
  if (typeof v === "boolean") return v ? "yes" : "no";
  if (Array.isArray(v)) return v.map(fmt).join(" × ");
  if (typeof v === "object") {
    return Object.entries(v).map(([k, x]) => k + ": " + fmt(x)).join(", ") || "—";
  }
  return String(v);
}

export function flagsText(v) {
  // Flags may arrive as a number (bit mask), a list of names, or an object of booleans.
  if (v === null || v === undefined) return "—";
  if (Array.isArray(v)) return v.length ? v.join(", ") : "none";
  if (typeof v === "number") return v === 0 ? "none" : "0x" + v.toString(16);
  if (typeof v === "object") {
    const parts = [];
    for (const [k, x] of Object.entries(v)) {
      if (x === true || (typeof x === "number" && x !== 0)) parts.push(typeof x === "number" ? k + "=" + fmt(x) : k);
      else if (Array.isArray(x) && x.length) parts.push(k + ": " + x.join(", "));
      else if (typeof x === "string" && x) parts.push(k + ": " + x);
      else if (x && typeof x === "object" && !Array.isArray(x)) {
        const inner = flagsText(x);
        if (inner !== "none") parts.push(k + ": " + inner);
      }
    }
    return parts.length ? parts.join("; ") : "none";
  }
  return String(v);
}

// Set an <img> src and wait until it has loaded; a failed load is an error.
export function loadImage(img, url) {
  return new Promise((resolve, reject) => {
    img.onload = () => { img.onload = img.onerror = null; img.dataset.loaded = url; resolve(); };
    img.onerror = () => {
      img.onload = img.onerror = null;
      reject(new ApiError("GET " + url.split("?")[0] + " failed to load"));
    };
    img.src = url;
  });
}

export function humanBytes(n) {
  if (typeof n !== "number") return "";
  if (n < 1024) return n + " B";
  if (n < 1048576) return (n / 1024).toFixed(0) + " KiB";
  return (n / 1048576).toFixed(1) + " MiB";
}

export function hasFlags(v) {
  const t = flagsText(v);
  return t !== "none" && t !== "—";
}
