// Recordings (issue 13, item 4): record N seconds (or until stopped) of raw pairs, list them,
// download them as zip, replay them through the virtual camera, delete them with undo (as captures:
// DELETE moves it into the daemon's trash at once, "Undo" in the message asks POST .../restore).
//
// Contract: stereocam/server/API.md, "Recordings" (and POST /api/virtual-camera {"recording": id}).
//
// init(ctx) — call once after the DOM is ready. ctx gives:
//   ctx.api(method, path, body)  core.js's api(): JSON in and out, throws ApiError on non-2xx
//   ctx.showError(errOrText)     core.js's showError(): an ApiError or a string
//   ctx.showInfo(text)           core.js's showInfo(): a message that fades
//   ctx.$(id)                    document.getElementById
//   ctx.onReplay                 (optional) called with the POST /api/virtual-camera reply after a
//                                 replay starts (e.g. setSourceRadios("virtual") from source.js)
// Returns { refresh }: refresh() reloads the list (also exported).
//
// HTML (a panel of its own, e.g. after the Captures panel):
//
//   <section class="panel" aria-labelledby="h-recordings" id="recordings-panel" data-testid="recordings-panel">
//     <h2 id="h-recordings">Recordings</h2>
//     <form id="record-form" data-testid="record-form" class="row">
//       <label>seconds <input type="number" id="record-seconds" data-testid="record-seconds"
//              min="0.1" max="86400" step="any" value="10"></label>
//       <label><input type="checkbox" id="record-until-stopped" data-testid="record-until-stopped">
//              until stopped</label>
//       <button type="submit" id="btn-record" data-testid="btn-record" class="primary">Record</button>
//       <button type="button" id="btn-record-stop" data-testid="btn-record-stop" hidden>Stop</button>
//     </form>
//     <p id="record-status" data-testid="record-status" class="muted" aria-live="polite"></p>
//     <ul id="recordings-list" data-testid="recordings-list" class="captures"></ul>
//   </section>
//
// Test hooks: #recordings-panel data-recording = the running recording's id ("" when none);
// #recordings-list data-count; each <li data-testid="recording" data-id data-state data-frames
// data-end> holds button[data-testid=recording-view] (the viewer, frame by frame),
// a[data-testid=recording-download], button[data-testid=recording-replay] and
// button[data-testid=recording-delete] (deletes at once; the message [data-testid=message-undo] offers
// button[data-testid=btn-undo] for UNDO_MS).
import { undoMessage } from "./core.js";
import { openRecording } from "./viewer.js";

const POLL_MS = 1000;
const hidden = new Set();  // deleted here, DELETE not answered yet: never shown again by a refresh
let ctx = null;
let timer = null;
let running = null;  // the id of the recording running, as last listed

function fmtSeconds(s) {
  return typeof s === "number" ? (s < 10 ? s.toFixed(1) : s.toFixed(0)) + " s" : "";
}

function humanBytes(n) {
  if (typeof n !== "number") return "";
  if (n < 1024) return n + " B";
  if (n < 1048576) return (n / 1024).toFixed(0) + " KiB";
  if (n < 1073741824) return (n / 1048576).toFixed(1) + " MiB";
  return (n / 1073741824).toFixed(2) + " GiB";
}

function describe(r) {
  const parts = [r.created];
  parts.push(r.frames + " frames");
  if (r.duration_s) parts.push(fmtSeconds(r.duration_s));
  if (r.fps) parts.push(r.fps.toFixed(1) + " fps");
  if (r.frame_size) parts.push(r.frame_size.join("×"));
  if (r.source) parts.push(r.source);
  parts.push(humanBytes(r.bytes));
  return parts.filter(Boolean).join(" · ");
}

// `hidden` alone loses to a stylesheet's display rule for buttons: set both.
function showElement(el, on) {
  el.hidden = !on;
  el.style.display = on ? "" : "none";
}

function button(label, testid, cls, onClick) {
  const b = document.createElement("button");
  b.type = "button";
  b.textContent = label;
  if (cls) b.className = cls;
  b.setAttribute("data-testid", testid);
  b.addEventListener("click", async () => {
    b.disabled = true;
    try { await onClick(); } catch (e) { ctx.showError(e); } finally { b.disabled = false; }
  });
  return b;
}

function item(r) {
  const li = document.createElement("li");
  li.setAttribute("data-testid", "recording");
  li.dataset.id = r.id;
  li.dataset.state = r.state;
  li.dataset.frames = String(r.frames);
  li.dataset.end = r.end || "";
  const info = document.createElement("div");
  info.className = "cap-info";
  const idEl = document.createElement("code");
  idEl.textContent = r.id;
  const meta = document.createElement("small");
  meta.textContent = describe(r);
  info.append(idEl, meta);
  if (r.state !== "done") {
    const note = document.createElement("small");
    note.className = "recording-live";
    note.textContent = r.state === "finishing" ? "writing its last " + (r.queued || 0) + " frames…" : "recording…";
    info.append(note);
    li.append(info);
    return li;
  }
  if (r.complete === false || r.error) {
    const warn = document.createElement("small");
    warn.className = "bad";
    warn.textContent = r.error || r.end_text || ("ended early: " + r.end);
    info.append(warn);
  }
  const dl = document.createElement("a");
  dl.href = "/api/recordings/" + encodeURIComponent(r.id) + ".zip";
  dl.textContent = "zip";
  dl.className = "btn";
  dl.setAttribute("download", r.id + ".zip");
  dl.setAttribute("data-testid", "recording-download");
  // frame by frame in the capture viewer (viewer.js): zoom, pan, pixel values, ←/→
  const view = button("view", "recording-view", "", () => openRecording(r.id));
  view.title = "step through its frames in the viewer (← →)";
  const replay = button("replay", "recording-replay", "", async () => {
    const res = await ctx.api("POST", "/api/virtual-camera", { recording: r.id });
    ctx.showInfo("Playing recording " + r.id + " through the core (" + r.frames + " frames, looping); " +
                 "choose another input or the live source to stop it.");
    if (typeof ctx.onReplay === "function") ctx.onReplay(res);
  });
  const del = button("delete", "recording-delete", "danger", async () => {
    // Gone from the list at once; the daemon moves it into its trash meanwhile.
    const url = "/api/recordings/" + encodeURIComponent(r.id);
    hidden.add(r.id);
    li.remove();
    try {
      await ctx.api("DELETE", url);
    } catch (e) {
      hidden.delete(r.id);
      await refresh().catch(() => {});
      throw e;
    }
    hidden.delete(r.id);
    undoMessage("Recording " + r.id + " deleted (" + r.frames + " frames, " + humanBytes(r.bytes) + ").",
      async () => {
        try {
          await ctx.api("POST", url + "/restore");
          ctx.showInfo("Recording " + r.id + " restored.");
          await refresh();
        } catch (e) {
          ctx.showError(e);
        }
      });
    await refresh();
  });
  li.append(info, view, dl, replay, del);
  return li;
}

function showRunning(doc) {
  const $ = ctx.$;
  const now = doc.recording;
  const entry = now ? doc.recordings.find((r) => r.id === now) : null;
  $("recordings-panel").dataset.recording = now || "";
  showElement($("btn-record"), !now);
  showElement($("btn-record-stop"), !!now);
  $("record-seconds").disabled = !!now || $("record-until-stopped").checked;
  $("record-until-stopped").disabled = !!now;
  const status = $("record-status");
  if (entry) {
    const of = entry.seconds ? " of " + fmtSeconds(entry.seconds) : "";
    status.textContent = "Recording " + entry.id + ": " + entry.frames + " frames, " +
                         fmtSeconds(entry.duration_s) + of + ".";
  } else if (running && !now) {
    // The one we watched has ended.
    const done = doc.recordings.find((r) => r.id === running);
    if (done) {
      status.textContent = "Recorded " + done.frames + " frames (" + fmtSeconds(done.duration_s) + ").";
      if (done.complete === false) ctx.showError("Recording " + done.id + " ended early: " + (done.end_text || done.end));
      else ctx.showInfo("Recording " + done.id + " is done: " + done.frames + " frames.");
    } else if (doc.last_error) {
      status.textContent = "";
      ctx.showError("The recording kept nothing: " + doc.last_error);
    }
  } else if (!now) {
    status.textContent = "";
  }
  running = now;
  schedule();
}

function schedule() {
  if (timer) clearTimeout(timer);
  timer = null;
  if (running) {
    timer = setTimeout(() => {
      if (document.hidden) { schedule(); return; }
      refresh().catch((e) => ctx.showError(e));
    }, POLL_MS);
  }
}

export async function refresh() {
  const doc = await ctx.api("GET", "/api/recordings");
  const list = ctx.$("recordings-list");
  const frag = document.createDocumentFragment();
  const items = ((doc && doc.recordings) || []).filter((r) => !hidden.has(r.id));
  for (const r of items) frag.append(item(r));
  if (!items.length) {
    const li = document.createElement("li");
    li.className = "empty";
    li.textContent = "no recordings yet";
    frag.append(li);
  }
  list.replaceChildren(frag);
  list.dataset.count = String(items.length);
  showRunning(doc || { recordings: [], recording: null });
}

async function start(ev) {
  ev.preventDefault();
  const $ = ctx.$;
  const btn = $("btn-record");
  btn.disabled = true;
  try {
    let body;
    if (!$("record-until-stopped").checked) {
      const seconds = Number($("record-seconds").value);
      if (!Number.isFinite(seconds) || seconds <= 0) {
        ctx.showError("Give the seconds to record (a number above 0), or tick “until stopped”.");
        return;
      }
      body = { seconds: seconds };
    }
    const rec = await ctx.api("POST", "/api/recordings", body);
    ctx.showInfo("Recording " + rec.id + (rec.seconds ? " for " + fmtSeconds(rec.seconds) : " until stopped") + ".");
    await refresh();
  } catch (e) {
    ctx.showError(e);
  } finally {
    btn.disabled = false;
  }
}

async function stop() {
  const btn = ctx.$("btn-record-stop");
  if (!running) return;
  btn.disabled = true;
  try {
    const done = await ctx.api("POST", "/api/recordings/" + encodeURIComponent(running) + "/stop");
    ctx.showInfo("Recording " + done.id + " stopped: " + done.frames + " frames (" + fmtSeconds(done.duration_s) + ").");
    running = null;
    await refresh();
  } catch (e) {
    ctx.showError(e);
    await refresh().catch(() => {});
  } finally {
    btn.disabled = false;
  }
}

export function init(c) {
  ctx = c;
  const $ = ctx.$;
  if (!$("recordings-panel")) return { refresh: refresh };
  $("record-form").addEventListener("submit", start);
  $("btn-record-stop").addEventListener("click", stop);
  $("record-until-stopped").addEventListener("change", (ev) => { $("record-seconds").disabled = ev.target.checked; });
  document.addEventListener("visibilitychange", () => { if (!document.hidden && running) refresh().catch(() => {}); });
  refresh().catch((e) => ctx.showError(e));
  return { refresh: refresh };
}
