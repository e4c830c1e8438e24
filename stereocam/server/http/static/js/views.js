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
  cap.append(view.caption + " ", span("frame-no", "frame-" + view.name), " ",
             span("view-rate", "rate-" + view.name, "rate-" + view.name));
  fig.append(cap);
  return fig;
}

// [{name, caption, alt, renders, gray, raw, worker, wide, readout}], in the registry's order.
export const VIEW_INFO = await loadRegistry();
export const VIEWS = VIEW_INFO.map((v) => v.name);
const box = document.getElementById("views");
for (const v of VIEW_INFO) box.append(figure(v));
box.dataset.viewsReady = VIEW_INFO.length ? "1" : "";
