// The status panel: GET /api/status once a second.
import { $, STATUS_PERIOD_MS, TOKEN, api, showError, fmt, flagsText, hasFlags } from "./core.js";
import { renderViewRates } from "./live.js";
import { setSourceRadios } from "./source.js";

let tokenHintShown = false;


function renderStatus(st) {
  const dl = $("status");
  const rows = [];
  const add = (key, label, value, cls) => rows.push([key, label, value, cls]);
  add("backend", "backend", fmt(st.backend) + (st.backend_reason ? " (" + st.backend_reason + ")" : ""));
  if (st.core_impl) add("core_impl", "rectify core", st.core_impl === "rtl" ? "RTL (Verilator)" : fmt(st.core_impl));
  add("source", "source", fmt(st.source) + (st.mux && st.mux !== st.source ? " (mux: " + fmt(st.mux) + ")" : ""));
  if (st.signal !== undefined) add("signal", "signal", st.signal ? "yes" : "NO SIGNAL", st.signal ? "" : "bad");
  if (st.last_frame && typeof st.last_frame === "object") {
    add("last_frame", "last frame", "#" + fmt(st.last_frame.frame) +
        (st.last_frame.age_s === null || st.last_frame.age_s === undefined ? "" : ", " + fmt(st.last_frame.age_s) + " s ago"));
  }
  add("frame_size", "frame size", fmt(st.frame_size));
  add("frames", "frames", fmt(st.frames) + (st.frames_seen !== undefined ? " copied of " + fmt(st.frames_seen) : ""));
  if (st.cpu) {
    add("cpu", "CPU", fmt(st.cpu.used_cores) + " of " + fmt(st.cpu.cores) + " cores" +
        (st.cpu.limited ? " (views lowered to " + fmt(st.cpu.rate_cap_fps) + " fps)" : ""), st.cpu.limited ? "warn" : "");
  }
  add("drops", "drops", fmt(st.drops));
  if (st.fps && typeof st.fps === "object") {
    for (const [stage, v] of Object.entries(st.fps)) {
      if (v && typeof v === "object") {
        for (const [sub, x] of Object.entries(v)) add("fps-" + stage + "-" + sub, "fps " + stage + " " + sub, fmt(x));
      } else {
        add("fps-" + stage, "fps " + stage, fmt(v));
      }
    }
  }
  if (st.core) {
    add("core-frame_count", "core frames", fmt(st.core.frame_count));
    add("core-flags", "core flags", flagsText(st.core.flags), hasFlags(st.core.flags) ? "bad" : "");
    add("core-control", "core control", flagsText(st.core.control));
    add("core-lb_rows", "line buffer rows", fmt(st.core.lb_rows));
  }
  if (st.vdma) add("vdma", "VDMA errors", flagsText(st.vdma), hasFlags(st.vdma) ? "bad" : "");
  if (st.calibration) {
    const c = st.calibration;
    add("calibration", "calibration", fmt(c.id) + " (rows " + fmt(c.rows_needed) + " of " + fmt(c.lb_rows) + ")");
  }
  if (st.virtual_camera && st.virtual_camera.input) add("virtual_input", "virtual input", fmt(st.virtual_camera.input));
  add("clients", "clients", fmt(st.clients) + (st.max_streams ? " of " + fmt(st.max_streams) : ""));
  add("uptime", "uptime", st.uptime_s === undefined ? "—" : fmt(st.uptime_s) + " s");
  if (st.sensors) add("sensors", "sensors", fmt(st.sensors));
  if (Array.isArray(st.errors) && st.errors.length) add("errors", "recent errors", st.errors.slice(-3).join(" | "), "bad");

  const frag = document.createDocumentFragment();
  for (const [key, label, value, cls] of rows) {
    const dt = document.createElement("dt");
    dt.textContent = label;
    const dd = document.createElement("dd");
    dd.textContent = value;
    dd.setAttribute("data-testid", "status-" + key);
    if (cls) dd.className = cls;
    frag.append(dt, dd);
  }
  dl.replaceChildren(frag);
  dl.dataset.updated = String(Date.now());
  $("backend").textContent = st.backend ? "backend: " + st.backend : "";
  if (st.access_token === true && !TOKEN && !tokenHintShown) {
    tokenHintShown = true;
    showError("this daemon needs an access token for changes (capture, source, cameras, upload, verify): " +
              "open the page as /?token=YOUR_TOKEN");
  }
  if (st.source) setSourceRadios(st.source);
  renderViewRates(st);
}


let statusFailing = false;
export async function refreshStatus() {
  try {
    const st = await api("GET", "/api/status");
    statusFailing = false;
    renderStatus(st);
  } catch (e) {
    // Report once per outage, not every second.
    if (!statusFailing) showError(e.message);
    statusFailing = true;
  } finally {
    setTimeout(refreshStatus, STATUS_PERIOD_MS);
  }
}
