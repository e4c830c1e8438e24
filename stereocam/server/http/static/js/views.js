// The live views' figures, built from the daemon's view registry (GET /api/views, the one list
// of views: stereocam/server/frames/views.py). No view is named in this page's HTML or scripts: a view
// added to the registry gets its figure, its place in the 1..N shortcuts and its WebSocket
// subscription from here. Every module that imports core.js waits for this one (top-level await),
// so the figures are in #views before any panel looks for them.
//
// Each figure (tests read these):
//   <figure class="view [view-wide]" data-view="NAME">
//     <img id="view-NAME" data-testid="view-NAME" alt="ALT" data-frame="">
//     [a raw view: <svg class="corners-overlay" id="corners-SIDE" data-testid="corners-SIDE" ...>]
//     <figcaption>CAPTION <span class="frame-no" id="frame-NAME"></span>
//       <span class="view-rate" id="rate-NAME" data-testid="rate-NAME"></span></figcaption>
//   </figure>
// #views gets data-views-ready="1" once built, or a line saying why there are none.
//
// The user's layout (issue 24, item 3): the Views menu (#views-menu) shows, hides and reorders
// the figures; the choice is kept in localStorage (LAYOUT_KEY: not a secret) and applied before
// the socket subscribes, so a hidden view is never asked of the daemon (no encoding for it).
// A change dispatches "stereocam:views-layout" on document (live.js re-subscribes).
const SVG = "http://www.w3.org/2000/svg";

async function loadRegistry() {
  try {
    const resp = await fetch("/api/views", { credentials: "same-origin" });
    if (!resp.ok) throw new Error("GET /api/views → " + resp.status);
    const doc = await resp.json();
    return doc.views;
  } catch (e) {
    const box = document.getElementById("views");
    const p = document.createElement("p");
    p.className = "muted";
    p.setAttribute("data-testid", "views-error");
    p.textContent = "The live views could not be listed (" + e.message + "): reload the page.";
    box.append(p);
    return [];
  }
}

function span(cls, id, testid) {
  const el = document.createElement("span");
  el.className = cls;
  el.id = id;
  if (testid) el.setAttribute("data-testid", testid);
  return el;
}

function figure(view) {
  const fig = document.createElement("figure");
  fig.className = view.wide ? "view view-wide" : "view";
  fig.dataset.view = view.name;
  const img = document.createElement("img");
  img.id = "view-" + view.name;
  img.setAttribute("data-testid", "view-" + view.name);
  img.alt = view.alt;
  img.dataset.frame = "";
  fig.append(img);
  if (view.raw) {  // the calibration panel draws the corners it found over the raw views
    const side = view.name.endsWith("_left") ? "left" : "right";
    const svg = document.createElementNS(SVG, "svg");
    svg.setAttribute("class", "corners-overlay");
    svg.id = "corners-" + side;
    svg.setAttribute("data-testid", "corners-" + side);
    svg.setAttribute("viewBox", "0 0 752 480");
    svg.setAttribute("preserveAspectRatio", "xMidYMid meet");
    svg.setAttribute("aria-hidden", "true");
    fig.append(svg);
  }
  const cap = document.createElement("figcaption");
  const note = span("view-note", "note-" + view.name, "note-" + view.name);
  note.hidden = true;  // "shown at N px: why" when the page could not ask for the size shown
  // net-NAME: the bytes/s this page receives of the view and its glass-to-glass latency (live.js)
  const name = document.createElement("span");
  name.className = "view-name";
  name.textContent = view.caption;
  cap.append(name, " ", span("frame-no", "frame-" + view.name), " ", note, " ",
             span("view-net", "net-" + view.name, "net-" + view.name), " ",
             span("view-rate", "rate-" + view.name, "rate-" + view.name));
  fig.append(cap);
  return fig;
}

// [{name, caption, alt, renders, gray, raw, worker, wide, readout}], in the registry's order.
export const VIEW_INFO = await loadRegistry();
export const VIEWS = VIEW_INFO.map((v) => v.name);
const box = document.getElementById("views");
for (const v of VIEW_INFO) box.append(figure(v));

// ---- the user's layout: which views, in which order ----------------------------------------------
export const LAYOUT_KEY = "stereocam.views-layout";

function loadLayout() {
  let doc = null;
  try { doc = JSON.parse(localStorage.getItem(LAYOUT_KEY) || "null"); } catch (e) { doc = null; }
  const known = new Set(VIEWS);
  const order = (doc && Array.isArray(doc.order) ? doc.order : []).filter((v) => known.has(v));
  // A view the registry gained since the layout was stored goes at its registry place (the end).
  for (const v of VIEWS) if (!order.includes(v)) order.push(v);
  const hidden = new Set((doc && Array.isArray(doc.hidden) ? doc.hidden : []).filter((v) => known.has(v)));
  const settings = {};
  const stored = doc && doc.settings && typeof doc.settings === "object" ? doc.settings : {};
  for (const v of VIEWS) settings[v] = checkedSettings(stored[v]);
  return { order: [...new Set(order)], hidden, settings };
}

// ---- each view's own quality, size and rate (issue 24, item 4) -----------------------------------
// A view's settings: {quality?, scale?, fps?}; a key left out is "auto" (quality: the daemon's
// default; size: the view's CSS width x devicePixelRatio, live.js; rate: the page's rate, ?fps=).
// The choices are values the daemon takes (it refuses others over the socket, API.md).
export const QUALITIES = [95, 90, 80, 70, 50, 30];
export const SIZES = [[1, "full"], [0.5, "half"], [0.25, "quarter"]];
export const RATES = [30, 15, 10, 5, 2, 1];

function checkedSettings(doc) {
  const out = {};
  if (!doc || typeof doc !== "object") return out;
  if (QUALITIES.includes(doc.quality)) out.quality = doc.quality;
  if (SIZES.some(([s]) => s === doc.scale)) out.scale = doc.scale;
  if (RATES.includes(doc.fps)) out.fps = doc.fps;
  return out;
}

/** A view's chosen settings ({} when every one is auto). */
export function viewSettings(view) { return (layout.settings && layout.settings[view]) || {}; }

const layout = loadLayout();

function saveLayout() {
  try {
    localStorage.setItem(LAYOUT_KEY, JSON.stringify({ order: layout.order, hidden: [...layout.hidden],
                                                      settings: layout.settings }));
  } catch (e) { /* storage refused (private mode, full): the layout lasts until the page reloads */ }
}

/** The views shown, in the user's order (what the socket asks for, what 1..N select). */
export function shownViews() { return layout.order.filter((v) => !layout.hidden.has(v)); }

function figureOf(view) { return box.querySelector('figure.view[data-view="' + view + '"]'); }

function applyLayout() {
  for (const v of layout.order) {
    const fig = figureOf(v);
    if (!fig) continue;
    box.append(fig);  // moving the figure keeps its listeners and its image
    fig.hidden = layout.hidden.has(v);
  }
  const none = $id("views-none");
  if (none) none.hidden = shownViews().length > 0;
}

function $id(id) { return document.getElementById(id); }

function changed() {
  saveLayout();
  applyLayout();
  renderMenu();
  document.dispatchEvent(new CustomEvent("stereocam:views-layout"));
}

function move(view, by, focusWhich) {
  const i = layout.order.indexOf(view);
  const j = i + by;
  if (i < 0 || j < 0 || j >= layout.order.length) return;
  [layout.order[i], layout.order[j]] = [layout.order[j], layout.order[i]];
  changed();
  // The focus stays on the moved view's button (keyboard users keep their place).
  const again = document.querySelector('#views-menu-list [data-view="' + view + '"] .' + focusWhich);
  if (again && !again.disabled) again.focus();
  else {
    const other = document.querySelector('#views-menu-list [data-view="' + view + '"] button:not(:disabled)');
    if (other) other.focus();
  }
}

function button(cls, text, label, testid, onClick, disabled) {
  const b = document.createElement("button");
  b.type = "button";
  b.className = cls;
  b.textContent = text;
  b.title = label;
  b.setAttribute("aria-label", label);
  b.setAttribute("data-testid", testid);
  b.disabled = disabled;
  b.addEventListener("click", onClick);
  return b;
}

function renderMenu() {
  const list = $id("views-menu-list");
  if (!list) return;
  list.replaceChildren();
  const info = Object.fromEntries(VIEW_INFO.map((v) => [v.name, v]));
  layout.order.forEach((v, i) => {
    const li = document.createElement("li");
    li.dataset.view = v;
    const label = document.createElement("label");
    const box = document.createElement("input");
    box.type = "checkbox";
    box.checked = !layout.hidden.has(v);
    box.setAttribute("data-testid", "views-show-" + v);
    box.addEventListener("change", () => {
      if (box.checked) layout.hidden.delete(v); else layout.hidden.add(v);
      changed();
      const again = $id("views-menu-list").querySelector('[data-view="' + v + '"] input');
      if (again) again.focus();
    });
    label.append(box, " " + info[v].caption);
    const opts = options(v, info[v].caption);
    const gear = button("views-opts", "⚙", info[v].caption + ": quality, size and rate", "views-opts-" + v,
                        () => {
                          opts.hidden = !opts.hidden;
                          gear.setAttribute("aria-expanded", opts.hidden ? "false" : "true");
                          openOptions[opts.hidden ? "delete" : "add"](v);
                        }, false);
    opts.hidden = !openOptions.has(v);
    gear.setAttribute("aria-expanded", opts.hidden ? "false" : "true");
    gear.setAttribute("aria-controls", opts.id);
    li.append(label,
              gear,
              button("views-up", "↑", "move " + info[v].caption + " up", "views-up-" + v,
                     () => move(v, -1, "views-up"), i === 0),
              button("views-down", "↓", "move " + info[v].caption + " down", "views-down-" + v,
                     () => move(v, 1, "views-down"), i === layout.order.length - 1),
              opts);
    list.append(li);
  });
}

const openOptions = new Set();  // views whose settings row is open in the menu (kept across re-renders)

function choice(v, key, label, choices, caption) {
  const lab = document.createElement("label");
  const sel = document.createElement("select");
  sel.setAttribute("data-testid", "views-" + key + "-" + v);
  sel.setAttribute("aria-label", caption + ": " + label);
  for (const [value, text] of [["auto", "auto"], ...choices]) {
    const o = document.createElement("option");
    o.value = String(value);
    o.textContent = text;
    sel.append(o);
  }
  const now = viewSettings(v)[key];
  sel.value = now === undefined ? "auto" : String(now);
  sel.addEventListener("change", () => {
    const mine = { ...viewSettings(v) };
    if (sel.value === "auto") delete mine[key]; else mine[key] = Number(sel.value);
    layout.settings[v] = mine;
    changed();
    const again = $id("views-menu-list").querySelector('[data-testid="views-' + key + "-" + v + '"]');
    if (again) again.focus();
  });
  lab.append(label + " ", sel);
  return lab;
}

function options(v, caption) {
  const box = document.createElement("div");
  box.className = "views-opts-row";
  box.id = "views-opts-row-" + v;
  box.setAttribute("data-testid", "views-opts-row-" + v);
  box.append(choice(v, "quality", "quality", QUALITIES.map((q) => [q, String(q)]), caption),
             choice(v, "scale", "size", SIZES, caption),
             choice(v, "fps", "fps", RATES.map((r) => [r, String(r)]), caption));
  return box;
}

const reset = $id("views-reset");
if (reset) {
  reset.addEventListener("click", () => {
    layout.order = [...VIEWS];
    layout.hidden.clear();
    for (const v of VIEWS) layout.settings[v] = {};
    changed();
  });
}
applyLayout();
renderMenu();
box.dataset.viewsReady = VIEW_INFO.length ? "1" : "";
