// Shared by every panel: the page's parameters, the access token, messages, the HTTP API
// and formatting.
//
// Contract: stereocam/server/API.md. All live views come over ONE WebSocket (/ws): browsers
// allow about 6 connections per host, so seven MJPEG <img> streams would starve the
// API calls. Each binary message is
//   [4-byte big-endian header length][UTF-8 JSON {view, frame, timestamp}][JPEG bytes]
// and becomes a blob URL on that view's <img>; the previous blob URL is revoked once
// the new one has loaded. Each <img> carries data-frame / data-timestamp of the frame
// it shows (tests read them).
//
// Access token: when the daemon has `access_token` set, the page asks GET /api/session (before any
// other request: a top-level await) and, without the right token, shows ONE "sign in" state
// (#signin: a plain form that POSTs the token to /signin, which works without this script) instead
// of a failure per request. With `protect: all` the views then wait for the sign-in (no socket, no
// polling, each view says so). The daemon answers a right token with its cookie (HttpOnly,
// SameSite=Strict) and a redirect back here; a wrong one with its sign-in page saying so. This
// script never holds the token: not in the URL, the history, localStorage, sessionStorage or a
// cookie it can read. Any 401 later (the daemon's token changed) brings the same state back.

// Errors: every failed API call shows a message in plain words in #messages, with the
// daemon's {"error": ...} text behind a disclosure; nothing is swallowed (see "messages").

export { VIEWS, VIEW_INFO } from "./views.js";  // the daemon's view registry (GET /api/views)
export const params = new URLSearchParams(window.location.search);
export const WS_FPS = clampNumber(params.get("fps"), 1, 60, 15);
export const STATUS_PERIOD_MS = 1000;
export const BACKOFF_MIN_MS = 500;
export const BACKOFF_MAX_MS = 10000;

export const $ = (id) => document.getElementById(id);

// Inputs whose keys are not text: a click on one must not turn the page's shortcuts off.
const NOT_TEXT = ["checkbox", "radio", "button", "submit", "reset", "range", "color", "file", "image"];

// Whether a key pressed on `target` belongs to it, not to the page's shortcuts: all keys while
// typing in a text field; on any other focused control (a clicked button, checkbox, radio,
// select), only the keys that operate it (Space, Enter, the arrows).
export function keyBelongsTo(target, key) {
  if (!(target instanceof HTMLElement)) return false;
  if (target.isContentEditable || target.tagName === "TEXTAREA") return true;
  if (target.tagName === "INPUT" && !NOT_TEXT.includes((target.type || "text").toLowerCase())) return true;
  const control = ["INPUT", "SELECT", "BUTTON", "SUMMARY"].includes(target.tagName);
  return control && (key === " " || key === "Enter" || key.startsWith("Arrow"));
}

export function clampNumber(text, lo, hi, fallback) {
  const n = Number(text);
  if (text === null || text === "" || !Number.isFinite(n)) return fallback;
  return Math.min(hi, Math.max(lo, n));
}

// ---- signing in ------------------------------------------------------------------
// Earlier pages kept the token in localStorage: it does not belong there (nor anywhere a script reads).
try { localStorage.removeItem("stereocam.token"); sessionStorage.removeItem("stereocam.token"); } catch (e) { /* storage disabled */ }

async function readSession() {
  try {
    const resp = await fetch("/api/session", { credentials: "same-origin", cache: "no-store" });
    return resp.ok ? await resp.json() : null;
  } catch (e) {
    return null;  // unreachable: the panels say so
  }
}
// {token_required, signed_in, token_sent, protect}; an unreachable daemon counts as signed in (the
// panels then say it is unreachable, which is the truth).
export const session = (await readSession()) ||
  { token_required: false, signed_in: true, token_sent: false, protect: "all" };

// True while every read needs the token and this browser has not given the right one: the views
// and panels wait (nothing polls, nothing retries) until the sign-in form reloads the page.
export function waitingForSignIn() {
  return session.token_required && !session.signed_in && session.protect === "all";
}

// Show the sign-in state: why (no token, or a wrong one), and, when reads need it, the views waiting.
export function showSignIn() {
  const box = $("signin");
  const why = session.token_sent
    ? "The access token this browser holds is wrong (the daemon's token may have changed): type the current one."
    : "This daemon needs its access token (its access_token setting, or stereocam serve --access-token) " +
      (session.protect === "all" ? "to show its views and status." : "for changes (capture, source, cameras, upload, verify).");
  $("signin-why").textContent = why;
  box.dataset.state = session.token_sent ? "wrong" : "missing";
  box.hidden = false;
  $("signout-form").hidden = true;
  if (!waitingForSignIn()) return;
  document.body.dataset.signin = "waiting";
  const conn = $("conn");
  conn.textContent = "waiting for sign-in";
  conn.className = "badge badge-warn";
  for (const fig of document.querySelectorAll("#views figure.view")) {
    fig.dataset.waiting = "sign-in";
    const caption = $("frame-" + fig.dataset.view);
    if (caption) caption.textContent = "waiting for sign-in";
  }
  document.dispatchEvent(new Event("stereocam:signin"));
}

// A 401 came: ask the daemon whether this browser is still signed in; if not, show the sign-in
// state (once). Resolves to true when the page now waits for the sign-in.
let signInShown = false;
export async function signInNeeded() {
  const now = await readSession();
  if (!now || now.signed_in) return false;
  Object.assign(session, now);
  if (!signInShown) { signInShown = true; showSignIn(); }
  const input = $("signin-token");
  if (input && document.activeElement !== input) input.focus();
  return waitingForSignIn();
}

// At start: the sign-in state, or (signed in with a token) the sign-out button.
export function initSignIn() {
  if (session.token_required && !session.signed_in) { signInShown = true; showSignIn(); }
  else if (session.token_required) $("signout-form").hidden = false;
}

// ---- messages -------------------------------------------------------------------
// Three kinds: "error" stays until dismissed; "success" and "info" fade by themselves after
// MESSAGE_FADE_MS. Each says in plain words what happened and what to do; the HTTP detail
// ("POST /api/verify → 409: ...") sits behind a disclosure (<details>). A message has a `key`,
// the kind of action it is about ("POST /api/virtual-camera"): a new error of that key replaces
// the old one, and any later success of that key (every api() call that succeeds, or
// clearMessages(key)) removes it, so a stale error never stays on top of a success. A message with
// the same kind and words as one shown replaces it. #messages never covers the views (style.css).
// data-testid: "message-error" for errors, "message-info" for the others.
export const MESSAGE_FADE_MS = 5000;
const MESSAGE_MAX = 6;
let messageSeq = 0;

export function showMessage(text, kind, opts) {
  kind = kind || "error";
  opts = opts || {};
  const box = $("messages");
  const key = opts.key || "";
  if (key) clearMessages(key, kind === "error" ? null : "error");
  // The same words again replace the message that says them (one message per problem, its fade
  // started again), never stack under it.
  for (const el of [...box.children]) {
    const said = el.querySelector(".msg-text");
    if (said && el.classList.contains("msg-" + kind) && said.textContent === text) el.remove();
  }
  const item = document.createElement("div");
  item.className = "msg msg-" + kind;
  item.setAttribute("data-testid", kind === "error" ? "message-error" : "message-info");
  item.setAttribute("role", kind === "error" ? "alert" : "status");
  item.id = "message-" + (++messageSeq);
  if (key) item.dataset.key = key;
  const body = document.createElement("div");
  body.className = "msg-body";
  const p = document.createElement("p");
  p.className = "msg-text";
  p.textContent = text;
  body.append(p);
  if (opts.detail) {
    const details = document.createElement("details");
    details.className = "msg-detail";
    const summary = document.createElement("summary");
    summary.textContent = opts.status ? "HTTP " + opts.status : "details";
    const code = document.createElement("code");
    code.textContent = opts.detail;
    details.append(summary, code);
    body.append(details);
  }
  const close = document.createElement("button");
  close.type = "button";
  close.className = "msg-close";
  close.setAttribute("aria-label", "dismiss");
  close.title = "dismiss";
  close.textContent = "×";
  close.addEventListener("click", () => item.remove());
  item.append(body, close);
  box.append(item);
  while (box.children.length > MESSAGE_MAX) box.firstElementChild.remove();
  if (kind !== "error") {
    // Fade, then go; while it has the keyboard focus (its disclosure or close button) it stays.
    let timer = null;
    const arm = () => {
      clearTimeout(timer);
      timer = setTimeout(() => {
        item.classList.add("msg-fading");
        timer = setTimeout(() => item.remove(), 600);
      }, opts.fadeMs || MESSAGE_FADE_MS);
    };
    item.addEventListener("focusin", () => { clearTimeout(timer); item.classList.remove("msg-fading"); });
    item.addEventListener("focusout", arm);
    arm();
  }
  return item;
}

// Remove the messages of `key` (only those of `kind` when given).
export function clearMessages(key, kind) {
  for (const el of [...$("messages").children]) {
    if (el.dataset.key === key && (!kind || el.classList.contains("msg-" + kind))) el.remove();
  }
}

export function showSuccess(text, key) { return showMessage(text, "success", { key: key }); }
export function showInfo(text, key) { return showMessage(text, "info", { key: key }); }

// An error as a message: `e` an ApiError (worded by `explain` and the generic rules below) or
// any other error; `text` a plain string.
export function showError(e, opts) {
  opts = opts || {};
  if (typeof e === "string") return showMessage(e, "error", { key: opts.key });
  if (e instanceof ApiError && e.status === 401) {
    // Not one more message: the one sign-in state says what to do.
    signInNeeded();
    return $("signin");
  }
  if (e instanceof ApiError) {
    return showMessage(explainError(e, opts), "error",
                       { key: opts.key || e.key, detail: e.http, status: e.status });
  }
  return showMessage("Something went wrong in the page: " + e + ". Reload it; if it happens again, " +
                     "report it with the browser console's output.", "error", { key: opts.key });
}

// ---- HTTP API -------------------------------------------------------------------
// An API failure: `method`, `path`, `status` (0: no answer) and `detail` (the daemon's
// {"error": ...} text, which says what to do). `message` keeps the one-line form
// "POST /api/verify → 409: ..." (`http`); an ApiError the page raises itself has no status.
export class ApiError extends Error {
  constructor(message, fields) {
    super(message);
    Object.assign(this, { method: null, path: null, status: null, detail: message, key: null }, fields || {});
    this.http = this.method ? message : null;
  }
}

// The kind of action a request is: the method and path without query or ids.
export function actionKey(method, path) {
  const clean = path.split("?")[0].split("/").map((seg) => (/\d/.test(seg) ? "*" : seg)).join("/");
  return method + " " + clean;
}

const sentence = (t) => { t = String(t || "").trim(); return t ? t[0].toUpperCase() + t.slice(1) : t; };
const stop = (t) => (/[.!?]$/.test(t) ? t : t + ".");

// Plain words for an ApiError. `opts.explain`: {status: text | (e) => text} or (e) => text|null,
// the panel's own wording; `opts.what`: what was tried ("Capture"), for the generic rules.
export function explainError(e, opts) {
  opts = opts || {};
  const ex = opts.explain;
  let own = null;
  if (typeof ex === "function") own = ex(e);
  else if (ex && e.status !== null && ex[e.status] !== undefined) {
    own = typeof ex[e.status] === "function" ? ex[e.status](e) : ex[e.status];
  }
  if (own) return own;
  const what = opts.what || (e.method ? describeRequest(e.method, e.path) : "");
  const failed = what ? what + " failed: " : "";
  const detail = stop(sentence(e.detail || ""));
  if (e.status === null) return sentence(failed + e.detail);
  if (e.status === 0) {
    return failed + "the daemon did not answer. Check that stereocam is running and that this computer " +
           "can reach the board, then try again.";
  }
  if (e.status === 401) {
    return (what || "This change") + " needs the daemon's access token: sign in with the form at the " +
           "top of the page (it is remembered).";
  }
  if (e.status === 403) return failed + "the daemon takes changes only from its own page. " + detail;
  if (e.status === 413) return failed + "that is more than the daemon accepts. " + detail;
  if (e.status === 507) return failed + "the board's disk is full. Delete captures or calibration pairs, then try again.";
  if (e.status >= 500) return failed + detail + " If it persists, see the daemon's log.";
  return failed + detail;
}

const REQUESTS = [
  ["POST /api/captures", "Capture"],
  ["DELETE /api/captures/*", "Deleting the capture"],
  ["POST /api/virtual-camera", "Sending the images through the fabric"],
  ["POST /api/verify", "Verify"],
  ["PUT /api/source", "Switching the source"],
  ["GET /api/cameras", "Reading the camera settings"],
  ["PUT /api/cameras", "Changing the camera setting"],
  ["GET /api/status", "Reading the daemon's status"],
  ["POST /api/calibration/pairs", "Capturing a calibration pair"],
  ["DELETE /api/calibration/pairs", "Deleting the calibration pairs"],
  ["DELETE /api/calibration/pairs/*", "Deleting the calibration pair"],
  ["POST /api/calibration/compute", "Computing the calibration"],
  ["POST /api/calibration/apply", "Applying the calibration"],
  ["GET /api/calibration/corners", "Finding the board's corners"],
  ["PUT /api/calibration/session", "Changing the calibration settings"],
];
export function describeRequest(method, path) {
  const key = actionKey(method, path);
  const hit = REQUESTS.find(([k]) => k === key);
  return hit ? hit[1] : method + " " + path.split("?")[0];
}

// fetch + JSON; any non-2xx becomes ApiError with the daemon's "error" text. A success clears the
// error messages of the same kind of action (actionKey).
export async function api(method, path, body) {
  const init = { method: method, headers: {} };
  if (body instanceof FormData) {
    init.body = body;
  } else if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  const key = actionKey(method, path);
  let resp;
  try {
    resp = await fetch(path, init);
  } catch (e) {
    throw new ApiError(method + " " + path + ": the daemon is unreachable (" + e.message + ")",
                       { method: method, path: path, status: 0, detail: "the daemon is unreachable (" + e.message + ")",
                         key: key });
  }
  const text = await resp.text();
  let data = null;
  if (text) {
    try { data = JSON.parse(text); } catch (e) { data = null; }
  }
  if (!resp.ok) {
    const why = data && typeof data.error === "string" ? data.error : (text.trim().slice(0, 200) || resp.statusText);
    throw new ApiError(method + " " + path + " → " + resp.status + ": " + why,
                       { method: method, path: path, status: resp.status, detail: why, key: key });
  }
  clearMessages(key, "error");
  return data;
}

// Run an async UI action with its button disabled; errors go to #messages, worded with
// `opts` (see explainError; `opts.key` names the action when it is not one request).
export async function action(button, fn, opts) {
  // A disabled button loses the focus: give it back when the action ends, so that a keyboard
  // user stays where they were.
  const focused = button && document.activeElement === button;
  if (button) button.disabled = true;
  try {
    const result = await fn();
    if (opts && opts.key) clearMessages(opts.key, "error");
    return result;
  } catch (e) {
    showError(e, opts);
    return undefined;
  } finally {
    if (button) button.disabled = false;
    if (focused && (document.activeElement === document.body || document.activeElement === null)) button.focus();
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
      reject(new ApiError("the image " + url.split("?")[0] + " did not load: try again, or reload the page"));
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

// Delete with undo (captures, recordings): the item is deleted on the daemon at once (into its trash)
// and the message offers Undo for UNDO_MS.
export const UNDO_MS = 8000;

// A message with an Undo button, in the page's message area, gone after UNDO_MS.
export function undoMessage(text, onUndo) {
  const item = document.createElement("div");
  item.className = "msg msg-info msg-undo";
  item.setAttribute("data-testid", "message-undo");
  item.setAttribute("role", "status");
  const span = document.createElement("span");
  span.textContent = text;
  const undo = document.createElement("button");
  undo.type = "button";
  undo.className = "undo";
  undo.textContent = "Undo";
  undo.setAttribute("data-testid", "btn-undo");
  const close = document.createElement("button");
  close.type = "button";
  close.className = "msg-close";
  close.setAttribute("aria-label", "dismiss");
  close.textContent = "×";
  const timer = setTimeout(() => item.remove(), UNDO_MS);
  undo.addEventListener("click", async () => {
    clearTimeout(timer);
    undo.disabled = true;
    await onUndo();
    item.remove();
  });
  close.addEventListener("click", () => { clearTimeout(timer); item.remove(); });
  item.append(span, undo, close);
  $("messages").append(item);
  return item;
}
