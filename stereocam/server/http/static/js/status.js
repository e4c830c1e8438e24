// The status panel: GET /api/status once a second, shown in groups (fabric, cameras, core,
// calibration, clients). Every value is a <dd data-testid="status-KEY"> (tests read them).
//
// Signal, one truth: the daemon's frame feed. /api/status `signal` is true while a frame came
// within `no_signal_s`; the WebSocket sends each view's "NO SIGNAL" frame (header `signal`:
// false) on exactly that condition. The panel says NO SIGNAL when the daemon does, says how long
// since the last frame (`last_frame.age_s`), and calls the signal intermittent when it came and
// went over the last seconds (the views then show NO SIGNAL between frames), so it never says
// "yes" while the views keep showing NO SIGNAL.
import { $, STATUS_PERIOD_MS, api, waitingForSignIn, showError, fmt, flagsText, hasFlags } from "./core.js";
import { renderViewRates } from "./live.js";
import { setSourceRadios } from "./source.js";

const GROUPS = [
  ["fabric", "Fabric"], ["cameras", "Cameras"], ["core", "Rectify core"], ["stereo", "Disparity"],
  ["calibration", "Calibration"], ["clients", "Clients"], ["errors", "Recent errors"],
];
const SIGNAL_WINDOW = 10;  // polls (seconds) over which a signal that came and went is "intermittent"
const signalHistory = [];

function ago(s) {
  if (typeof s !== "number") return "";
  if (s < 10) return s.toFixed(2) + " s ago";
  if (s < 120) return Math.round(s) + " s ago";
  return Math.round(s / 60) + " min ago";
}

function duration(s) {
  if (typeof s !== "number") return "—";
  if (s < 120) return Math.round(s) + " s";
  if (s < 7200) return Math.round(s / 60) + " min";
  return (s / 3600).toFixed(1) + " h";
}

function signalRow(st) {
  signalHistory.push(!!st.signal);
  while (signalHistory.length > SIGNAL_WINDOW) signalHistory.shift();
  const age = st.last_frame ? st.last_frame.age_s : null;
  if (!st.signal) {
    const since = typeof age === "number" ? "no frame for " + age.toFixed(1) + " s" : "no frame yet";
    return ["NO SIGNAL: " + since + " (the views show NO SIGNAL)", "bad", "no"];
  }
  // Came and went more than once lately: the views flicker to NO SIGNAL between frames. (One
  // outage that ended is not intermittent: the views show frames again, so does this.)
  const gaps = signalHistory.filter((x) => !x).length;
  const recoveries = signalHistory.filter((x, i) => i > 0 && x && !signalHistory[i - 1]).length;
  if (recoveries >= 2) {
    return ["intermittent: no frame for a while in " + gaps + " of the last " + signalHistory.length +
            " s (the views show NO SIGNAL between frames)", "warn", "intermittent"];
  }
  return ["yes: frames flowing", "ok", "yes"];
}

function cameraRow(name, health, values) {
  if (health && health.ok === false) {
    return ["NOT ANSWERING" + (health.error ? ": " + health.error : ""), "bad"];
  }
  const parts = [health && health.ok ? "ok" : "—"];
  if (values) {
    if (typeof values.exposure_us === "number") parts.push("exposure " + (values.exposure_us / 1000).toFixed(1) + " ms");
    if (typeof values.gain === "number") parts.push("gain " + values.gain.toFixed(1));
    const auto = [values.aec ? "exposure" : "", values.agc ? "gain" : ""].filter(Boolean);
    parts.push("auto " + (auto.length ? auto.join(" + ") : "off"));
    if (values.flip_h || values.flip_v) parts.push("flipped " + [values.flip_h ? "H" : "", values.flip_v ? "V" : ""].join(""));
    if (values.test_pattern) parts.push("test pattern " + values.test_pattern);
  }
  return [parts.join(" · "), ""];
}

function renderStatus(st) {
  const rows = {};
  for (const [g] of GROUPS) rows[g] = [];
  const add = (group, key, label, value, cls) => rows[group].push([key, label, value, cls]);

  // fabric
  add("fabric", "backend", "backend", fmt(st.backend) + (st.backend_reason ? " (" + st.backend_reason + ")" : ""));
  // A board without its bitstream runs the emulated fabric: said first, in red (backend.py's warning).
  if (st.backend_warning) add("fabric", "backend_warning", "WARNING", st.backend_warning, "bad");
  add("fabric", "source", "source", fmt(st.source) + (st.mux && st.mux !== st.source ? " (mux: " + fmt(st.mux) + ")" : ""));
  if (st.signal !== undefined) {
    const [text, cls, state] = signalRow(st);
    add("fabric", "signal", "signal", text, cls);
    $("status").dataset.signal = state;
  }
  if (st.last_frame && typeof st.last_frame === "object") {
    add("fabric", "last_frame", "last frame", "#" + fmt(st.last_frame.frame) +
        (typeof st.last_frame.age_s === "number" ? ", " + ago(st.last_frame.age_s) : ""));
  }
  add("fabric", "frame_size", "frame size", fmt(st.frame_size));
  const fps = st.fps || {};
  add("fabric", "fps-camera", "frame rate", fmt(fps.camera) + " fps from the core, " + fmt(fps.pipeline) + " fps copied");
  add("fabric", "frames", "frames", fmt(st.frames) + (st.frames_seen !== undefined ? " copied of " + fmt(st.frames_seen) : ""));
  // Dropped frames are normal when the copy (or the CPU) is slower than the cameras: say what they are.
  add("fabric", "drops", "drops", st.drops ? fmt(st.drops) + " frames the core completed but the daemon " +
      "did not copy (it was busy; the views skip them)" : fmt(st.drops), st.drops ? "warn" : "");
  if (st.vdma) add("fabric", "vdma", "DMA errors", flagsText(st.vdma), hasFlags(st.vdma) ? "bad" : "");
  const faults = Array.isArray(st.faults) ? st.faults : [];
  add("fabric", "faults", "faults", faults.length ? faults.map((f) => f.what + ": " + f.text).join("; ") : "none",
      faults.length ? "bad" : "");
  if (st.virtual_camera && st.virtual_camera.input) add("fabric", "virtual_input", "virtual input", fmt(st.virtual_camera.input));
  // A recording playing through the virtual camera; one that stopped on an error says why until the next input.
  const playing = st.virtual_camera && st.virtual_camera.playing;
  if (playing && typeof playing === "object") {
    const where = "recording " + fmt(playing.recording) + ", frame " + fmt(playing.frame) + " of " + fmt(playing.frames);
    if (playing.error) add("fabric", "playing", "playback", "stopped: " + playing.error + " (" + where + ")", "bad");
    else add("fabric", "playing", "playback", "playing " + where);
  }

  // cameras
  const sensors = st.sensors;
  if (sensors && typeof sensors === "object") {
    const health = sensors.health || {};
    const values = sensors.values || {};
    add("cameras", "sensors", "sensors",
        (sensors.ok ? "both answering" : "NOT all answering") + (health.sync ? " · " + health.sync : "") +
        (health.master ? " (master: " + health.master + ")" : ""), sensors.ok ? "" : "bad");
    for (const side of ["left", "right"]) {
      const [text, cls] = cameraRow(side, health[side], values[side]);
      add("cameras", "sensor-" + side, side, text, cls);
    }
  } else {
    add("cameras", "sensors", "sensors", "not reported by this backend");
  }

  // rectify core
  if (st.core_impl) add("core", "core_impl", "computed by", st.core_impl === "rtl" ? "RTL (Verilator)" : fmt(st.core_impl));
  if (st.core) {
    add("core", "core-frame_count", "frames", fmt(st.core.frame_count));
    add("core", "core-flags", "flags", flagsText(st.core.flags), hasFlags(st.core.flags) ? "bad" : "");
    add("core", "core-control", "control", flagsText(st.core.control));
    add("core", "core-lb_rows", "line buffer", fmt(st.core.lb_rows) + " rows" +
        (st.core.max_width ? ", up to " + fmt(st.core.max_width) + " px wide" : "") +
        (st.core.colour === undefined ? "" : st.core.colour ? ", colour" : ", gray"));
  } else {
    add("core", "core-frame_count", "registers", "unreadable", "bad");
  }

  // disparity: the stereo core, or the ARM where the bitstream has none
  if (st.disparity) {
    add("stereo", "disparity-by", "computed by", fmt(st.disparity.by));
    if (st.disparity.arm) add("stereo", "disparity-arm", "on the ARM", st.disparity.arm.text);
    const sc = st.disparity.stereo;
    if (sc) {
      add("stereo", "stereo-frame_count", "frames", fmt(sc.frame_count) + (sc.enabled ? "" : " (disabled)"));
      add("stereo", "stereo-flags", "flags", flagsText(sc.flags), hasFlags(sc.flags) ? "bad" : "");
      const p = sc.params || {};
      add("stereo", "stereo-params", "parameters", Object.keys(p).map((k) => k + " " + p[k]).join(", ") +
          (sc.apply_pending ? " (applying)" : ""));
    }
  }

  // calibration
  if (st.calibration) {
    const c = st.calibration;
    add("calibration", "calibration", "in use", fmt(c.id) + (c.changing ? " (being programmed)" : ""));
    if (c.description) add("calibration", "calibration-description", "what", fmt(c.description));
    add("calibration", "calibration-rows", "line buffer", "needs " + fmt(c.rows_needed) + " of " + fmt(c.lb_rows) + " rows");
  }

  // clients
  add("clients", "clients", "clients", fmt(st.clients) + (st.max_streams ? " of " + fmt(st.max_streams) : ""));
  if (st.cpu) {
    add("clients", "cpu", "CPU", fmt(st.cpu.used_cores) + " of " + fmt(st.cpu.cores) + " cores" +
        (st.cpu.limited ? " (views lowered to " + fmt(st.cpu.rate_cap_fps) + " fps)" : ""), st.cpu.limited ? "warn" : "");
  }
  const viewRates = Object.entries(fps).filter(([k, v]) => k !== "camera" && k !== "pipeline" && typeof v === "number");
  add("clients", "fps-views", "views encoded", viewRates.length ? viewRates.map(([k, v]) => k + " " + fmt(v)).join(" · ") + " fps" : "none");
  add("clients", "uptime", "daemon up", duration(st.uptime_s));

  if (Array.isArray(st.errors) && st.errors.length) add("errors", "errors", "last", st.errors.slice(-3).join(" | "), "bad");

  const frag = document.createDocumentFragment();
  for (const [group, title] of GROUPS) {
    if (!rows[group].length) continue;
    const section = document.createElement("section");
    section.className = "status-group";
    section.setAttribute("data-testid", "status-group-" + group);
    const h = document.createElement("h3");
    h.textContent = title;
    const dl = document.createElement("dl");
    dl.className = "status";
    for (const [key, label, value, cls] of rows[group]) {
      const dt = document.createElement("dt");
      dt.textContent = label;
      const dd = document.createElement("dd");
      dd.textContent = value;
      dd.setAttribute("data-testid", "status-" + key);
      if (cls) dd.className = cls;
      dl.append(dt, dd);
    }
    section.append(h, dl);
    frag.append(section);
  }
  const box = $("status");
  box.replaceChildren(frag);
  box.dataset.updated = String(Date.now());
  const badge = $("backend");
  badge.textContent = st.backend ? "backend: " + st.backend + (st.backend_warning ? " (NO BITSTREAM)" : "") : "";
  badge.className = st.backend_warning ? "badge badge-bad" : "badge";
  badge.title = st.backend_warning || "";
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
    // Report once per outage, not every second; the next answer clears it (api()).
    if (!statusFailing) showError(e, { what: "Reading the daemon's status" });
    statusFailing = true;
  } finally {
    // Waiting for the sign-in: no polling (the sign-in reloads the page, which starts it again).
    if (!waitingForSignIn()) setTimeout(refreshStatus, STATUS_PERIOD_MS);
  }
}
