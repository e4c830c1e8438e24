// Captures: list with thumbnails, the viewer, replay, download, delete with undo
// (GET/POST/DELETE /api/captures, GET /api/captures/{id}/thumb.jpg, POST /api/captures/{id}/restore).
//
// Delete with undo: the capture leaves the list at once and DELETE moves it into the daemon's trash
// straight away; "Undo" in the message (UNDO_MS) asks the daemon to restore it. Deleting on the daemon
// at once, not when the undo expires, is what loses nothing when the page is closed meanwhile: the
// delete the user asked for stands (no request left pending in a closed tab), and the files stay in
// the trash for ten minutes (a restore brings them back as they were).
import { $, api, action, showMessage, showError, humanBytes, undoMessage } from "./core.js";
import { openViewer, replayCapture } from "./viewer.js";

export { UNDO_MS } from "./core.js";
const hidden = new Set();  // deleted here, DELETE not answered yet: never shown again by a refresh

function captureUrl(id) { return "/api/captures/" + encodeURIComponent(id); }

// One of a capture's action buttons: its label, its test id and what a click does.
function actionButton(text, testid, onClick) {
  const b = document.createElement("button");
  b.type = "button";
  b.textContent = text;
  b.setAttribute("data-testid", testid);
  b.addEventListener("click", onClick);
  return b;
}

function captureItem(c) {
  const li = document.createElement("li");
  li.setAttribute("data-testid", "capture");
  li.dataset.id = c.id;
  const thumb = document.createElement("button");
  thumb.type = "button";
  thumb.className = "cap-thumb";
  thumb.title = "open in the viewer";
  thumb.setAttribute("aria-label", "open capture " + c.id + " in the viewer");
  thumb.setAttribute("data-testid", "capture-open");
  const img = document.createElement("img");
  img.alt = "";
  img.loading = "lazy";
  img.decoding = "async";
  img.src = captureUrl(c.id) + "/thumb.jpg";
  img.setAttribute("data-testid", "capture-thumb");
  img.addEventListener("error", () => { img.hidden = true; });
  thumb.append(img);
  thumb.addEventListener("click", () => openViewer(c.id));
  const info = document.createElement("div");
  info.className = "cap-info";
  const idEl = document.createElement("code");
  idEl.textContent = c.id;
  const meta = document.createElement("small");
  // The time in the browser's own time zone (the ISO UTC time the daemon gives stays as the title).
  const created = c.created ? new Date(c.created) : null;
  const when = created && !Number.isNaN(created.getTime()) ? created.toLocaleString() : c.created;
  if (c.created) meta.title = "created " + c.created;
  meta.dataset.created = c.created || "";
  meta.textContent = [when, c.source, c.frame !== undefined ? "frame " + c.frame : "",
                      humanBytes(c.bytes), c.error ? "damaged: " + c.error : ""].filter(Boolean).join(" · ");
  info.append(idEl, meta);
  const actions = document.createElement("div");
  actions.className = "cap-actions";
  const view = actionButton("view", "capture-view", () => openViewer(c.id));
  const replay = actionButton("replay", "capture-replay", () => replayCapture(c.id, replay));
  replay.title = "send its raw pair through the fabric (virtual camera)";
  const dl = document.createElement("a");
  dl.href = captureUrl(c.id) + ".zip";
  dl.textContent = "zip";
  dl.className = "btn";
  dl.setAttribute("download", c.id + ".zip");
  dl.setAttribute("data-testid", "capture-download");
  const del = actionButton("delete", "capture-delete", () => deleteCapture(c.id, li));
  del.className = "danger";
  actions.append(view, replay, dl, del);
  li.append(thumb, info, actions);
  return li;
}

function setCount() {
  const list = $("captures-list");
  const items = list.querySelectorAll("[data-testid=capture]");
  list.dataset.count = String(items.length);
  const empty = list.querySelector("li.empty");
  if (!items.length && !empty) {
    const li = document.createElement("li");
    li.className = "empty";
    li.textContent = "no captures yet";
    list.append(li);
  } else if (items.length && empty) {
    empty.remove();
  }
}

export async function refreshCaptures() {
  const data = await api("GET", "/api/captures");
  const list = $("captures-list");
  const frag = document.createDocumentFragment();
  const caps = ((data && data.captures) || []).filter((c) => !hidden.has(c.id));
  for (const c of caps) frag.append(captureItem(c));
  list.replaceChildren(frag);
  setCount();
}

async function deleteCapture(id, li) {
  // Gone from the list at once; the daemon moves it into its trash meanwhile.
  hidden.add(id);
  li.remove();
  setCount();
  try {
    await api("DELETE", captureUrl(id));
  } catch (e) {
    hidden.delete(id);
    showError(e);  // plain words, the HTTP line folded away (core.js)
    await action(null, refreshCaptures);
    return;
  } finally {
    hidden.delete(id);
  }
  undoMessage("Capture " + id + " deleted.", () => action(null, async () => {
    await api("POST", captureUrl(id) + "/restore");
    showMessage("Capture " + id + " restored.", "info");
    await refreshCaptures();
  }));
}

export function initCaptures() {
  $("btn-capture").addEventListener("click", (ev) => action(ev.currentTarget, async () => {
    const res = await api("POST", "/api/captures");
    showMessage("captured " + (res && res.id ? res.id : ""), "info");
    await refreshCaptures();
  }));
  action(null, refreshCaptures);
}
