// Keyboard shortcuts, and the "?" overlay listing them. Never while typing in a field, never
// with Ctrl, Alt or Meta (the browser's own shortcuts stay theirs).
//
// Each shortcut clicks the page's own control, so it does exactly what the click does (errors,
// messages, disabled buttons included). The calibration panel's Space / C (calibration.js) and
// the views' Enter / Escape (live.js) are listed here too, handled where they are.
import { $, VIEWS, VIEW_INFO, keyBelongsTo } from "./core.js";
import { chooseSource } from "./source.js";

function click(id) {
  const el = $(id);
  if (el && !el.disabled) el.click();
}

function enlargedView() { return document.querySelector("#views figure.view-enlarged"); }

function toggleFullscreen() {
  if (document.fullscreenElement) { document.exitFullscreen().catch(() => {}); return; }
  const fig = enlargedView() || (document.activeElement && document.activeElement.closest &&
                                 document.activeElement.closest("#views figure.view"));
  if (fig && fig.requestFullscreen) fig.requestFullscreen().catch(() => {});
}

// the shown views in their order on screen (the Views menu hides and reorders them)
function viewFigure(n) { return document.querySelectorAll("#views figure.view:not([hidden])")[n - 1] || null; }

const VIEW_KEYS = VIEWS.slice(0, 9).map((v, i) => String(i + 1));

// [keys shown, what it does, key values that trigger it, handler or null (handled elsewhere)]
export const SHORTCUTS = [
  [["p"], "Capture (store raw and rectified pairs)", ["p", "P"], () => click("btn-capture")],
  [["v"], "Verify the fabric against the model", ["v", "V"], () => click("btn-verify")],
  [["l"], "Source: live cameras", ["l", "L"], () => chooseSource("live")],
  [["u"], "Source: virtual camera (the uploaded pair)", ["u", "U"], () => chooseSource("virtual")],
  // One digit per view of the registry, in its order (the page's figures): 1 to 9 at most.
  [["1", "…", String(VIEW_KEYS.length)], "Enlarge view 1 to " + VIEW_KEYS.length + " (again: back to the thumbnail)",
   VIEW_KEYS, (ev) => { const fig = viewFigure(Number(ev.key)); if (fig) { fig.click(); fig.focus(); } }],
  [["z"], "Freeze the live views (again: resume)", ["z", "Z"], () => click("btn-freeze")],
  [["r"], "Ruler on or off (Esc clears its points)", ["r", "R"], () => click("btn-ruler")],
  [["f"], "Fullscreen the enlarged view (again: leave)", ["f", "F"], () => toggleFullscreen()],
  [["Enter"], "On a focused view: enlarge it", [], null],
  [["Esc"], "Back to the thumbnails; close this list", [], null],
  [["Space", "C"], "Calibration panel open: capture a calibration pair", [], null],
  [["?"], "Show or hide this list", ["?"], () => toggleOverlay()],
];

function buildOverlay() {
  const dialog = document.createElement("dialog");
  dialog.id = "shortcuts";
  dialog.className = "shortcuts";
  dialog.setAttribute("data-testid", "shortcuts");
  dialog.setAttribute("aria-labelledby", "shortcuts-title");
  const head = document.createElement("div");
  head.className = "shortcuts-head";
  const h = document.createElement("h2");
  h.id = "shortcuts-title";
  h.textContent = "Keyboard shortcuts";
  const close = document.createElement("button");
  close.type = "button";
  close.className = "msg-close";
  close.setAttribute("aria-label", "close");
  close.textContent = "×";
  close.addEventListener("click", () => dialog.close());
  head.append(h, close);
  const table = document.createElement("table");
  const tbody = document.createElement("tbody");
  for (const [keys, what] of SHORTCUTS) {
    const tr = document.createElement("tr");
    tr.setAttribute("data-testid", "shortcut");
    const k = document.createElement("td");
    keys.forEach((key, i) => {
      if (key === "…") { k.append(" – "); return; }
      if (i && keys[i - 1] !== "…") k.append(" or ");
      const kbd = document.createElement("kbd");
      kbd.textContent = key;
      k.append(kbd);
    });
    const d = document.createElement("td");
    d.textContent = what;
    tr.append(k, d);
    tbody.append(tr);
  }
  table.append(tbody);
  const note = document.createElement("p");
  note.className = "muted";
  note.textContent = "Not while typing in a field. Views are numbered as on the page: " +
                     VIEW_INFO.map((v) => v.caption.replace(/ \(.*\)$/, "")).join(", ") + ".";
  dialog.append(head, table, note);
  // A click on the backdrop (outside the box) closes it.
  dialog.addEventListener("click", (ev) => { if (ev.target === dialog) dialog.close(); });
  dialog.addEventListener("close", () => { document.body.dataset.shortcuts = "closed"; });
  document.body.append(dialog);
  return dialog;
}

let overlay = null;
export function toggleOverlay(force) {
  if (!overlay) overlay = buildOverlay();
  const open = force === undefined ? !overlay.open : force;
  if (open && !overlay.open) overlay.showModal();
  else if (!open && overlay.open) overlay.close();
  document.body.dataset.shortcuts = open ? "open" : "closed";
}

export function initShortcuts() {
  const button = $("btn-shortcuts");
  if (button) button.addEventListener("click", () => toggleOverlay());
  document.addEventListener("keydown", (ev) => {
    if (ev.defaultPrevented || ev.repeat || ev.ctrlKey || ev.metaKey || ev.altKey || keyBelongsTo(ev.target, ev.key)) return;
    if (overlay && overlay.open) {
      // The list is modal: only "?" (and Escape, the dialog's own) act while it is open.
      if (ev.key === "?") { ev.preventDefault(); toggleOverlay(false); }
      return;
    }
    for (const [, , keys, handler] of SHORTCUTS) {
      if (handler && keys.includes(ev.key)) {
        ev.preventDefault();
        handler(ev);
        return;
      }
    }
  });
}
