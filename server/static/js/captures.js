// Captures: list, download, delete (GET/POST/DELETE /api/captures).
import { $, api, action, showMessage, humanBytes } from "./core.js";

// ---- captures -------------------------------------------------------------------

export async function refreshCaptures() {
  const data = await api("GET", "/api/captures");
  const list = $("captures-list");
  const frag = document.createDocumentFragment();
  const caps = (data && data.captures) || [];
  for (const c of caps) {
    const li = document.createElement("li");
    li.setAttribute("data-testid", "capture");
    li.dataset.id = c.id;
    const info = document.createElement("div");
    info.className = "cap-info";
    const idEl = document.createElement("code");
    idEl.textContent = c.id;
    const meta = document.createElement("small");
    meta.textContent = [c.created, c.source, c.frame !== undefined ? "frame " + c.frame : "",
                        humanBytes(c.bytes)].filter(Boolean).join(" · ");
    info.append(idEl, meta);
    const dl = document.createElement("a");
    dl.href = "/api/captures/" + encodeURIComponent(c.id) + ".zip";
    dl.textContent = "zip";
    dl.className = "btn";
    dl.setAttribute("download", c.id + ".zip");
    dl.setAttribute("data-testid", "capture-download");
    const del = document.createElement("button");
    del.type = "button";
    del.textContent = "delete";
    del.className = "danger";
    del.setAttribute("data-testid", "capture-delete");
    del.addEventListener("click", () => action(del, async () => {
      await api("DELETE", "/api/captures/" + encodeURIComponent(c.id));
      await refreshCaptures();
    }));
    li.append(info, dl, del);
    frag.append(li);
  }
  if (!caps.length) {
    const li = document.createElement("li");
    li.className = "empty";
    li.textContent = "no captures yet";
    frag.append(li);
  }
  list.replaceChildren(frag);
  list.dataset.count = String(caps.length);
}


export function initCaptures() {
  $("btn-capture").addEventListener("click", (ev) => action(ev.currentTarget, async () => {
    const res = await api("POST", "/api/captures");
    showMessage("captured " + (res && res.id ? res.id : ""), "info");
    await refreshCaptures();
  }));
  action(null, refreshCaptures);
}
