// stereocam page: plain JS, no framework, no outside assets (the board has no internet).
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
"use strict";

(function () {
  const VIEWS = ["raw_left", "raw_right", "rect_left", "rect_right", "sbs", "anaglyph", "disparity"];
  const TOKEN_KEY = "stereocam.token";
  const params = new URLSearchParams(window.location.search);
  const WS_FPS = clampNumber(params.get("fps"), 1, 60, 15);
  const STATUS_PERIOD_MS = 1000;
  const BACKOFF_MIN_MS = 500;
  const BACKOFF_MAX_MS = 10000;

  const $ = (id) => document.getElementById(id);

  function clampNumber(text, lo, hi, fallback) {
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
  const TOKEN = readToken();
  // Streams, snapshots and the WebSocket cannot carry a header: with `protect: all` the daemon
  // reads the token from this cookie (same site only, so a page of another origin never sends it).
  document.cookie = "stereocam_token=" + (TOKEN ? encodeURIComponent(TOKEN) + "; max-age=31536000"
                                                : "; max-age=0") + "; path=/; SameSite=Strict";

  // ---- messages -------------------------------------------------------------------
  let messageSeq = 0;
  function showMessage(text, kind) {
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
  function showError(text) { showMessage(text, "error"); }

  // ---- HTTP API -------------------------------------------------------------------
  class ApiError extends Error {}

  // fetch + JSON; any non-2xx becomes ApiError with the daemon's "error" text.
  async function api(method, path, body) {
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
  async function action(button, fn) {
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

  function bust(url) { return url + (url.includes("?") ? "&" : "?") + "t=" + Date.now(); }

  // ---- live views over one WebSocket ----------------------------------------------
  const decoder = new TextDecoder("utf-8");
  const live = {};  // view -> {img, url (current blob URL), frames, caption}
  for (const v of VIEWS) live[v] = { img: $("view-" + v), url: null, caption: $("frame-" + v), frames: 0 };

  let ws = null;
  let backoff = BACKOFF_MIN_MS;
  let reconnectTimer = null;
  let everConnected = false;

  function setConn(text, cls) {
    const el = $("conn");
    el.textContent = text;
    el.className = "badge " + cls;
  }

  function showFallback(text) {
    const el = $("ws-fallback");
    if (text) { el.textContent = text; el.hidden = false; } else { el.textContent = ""; el.hidden = true; }
  }

  function onFrame(buf) {
    if (!(buf instanceof ArrayBuffer) || buf.byteLength < 4) return;
    const hlen = new DataView(buf).getUint32(0, false);
    if (4 + hlen > buf.byteLength) return;
    let header;
    try { header = JSON.parse(decoder.decode(new Uint8Array(buf, 4, hlen))); } catch (e) { return; }
    const slot = live[header.view];
    if (!slot) return;
    const url = URL.createObjectURL(new Blob([new Uint8Array(buf, 4 + hlen)], { type: "image/jpeg" }));
    const previous = slot.url;
    slot.url = url;
    const img = slot.img;
    slot.frames += 1;
    const received = slot.frames;
    img.onload = () => {
      // data-frame names the frame actually on screen: set once the JPEG has decoded.
      if (previous) URL.revokeObjectURL(previous);
      img.onload = img.onerror = null;
      img.dataset.frame = String(header.frame);
      // The decoded size, read here because naturalWidth is 0 again while the next src loads.
      img.dataset.size = img.naturalWidth + "x" + img.naturalHeight;
      img.dataset.timestamp = String(header.timestamp);
      img.dataset.received = String(received);
      if (slot.caption) slot.caption.textContent = "#" + header.frame;
    };
    img.onerror = () => {
      if (previous) URL.revokeObjectURL(previous);
      img.onload = img.onerror = null;
    };
    img.src = url;
  }

  function connect() {
    reconnectTimer = null;
    const proto = window.location.protocol === "https:" ? "wss:" : "ws:";
    const sock = new WebSocket(proto + "//" + window.location.host + "/ws");
    sock.binaryType = "arraybuffer";
    ws = sock;
    setConn(everConnected ? "reconnecting…" : "connecting…", "badge-warn");
    sock.onopen = () => {
      everConnected = true;
      backoff = BACKOFF_MIN_MS;
      setConn("live", "badge-ok");
      showFallback("");
      sock.send(JSON.stringify({ views: VIEWS, fps: WS_FPS }));
    };
    sock.onmessage = (ev) => {
      if (typeof ev.data === "string") {
        // The daemon may send a JSON text message (e.g. {"error": ...}).
        try {
          const msg = JSON.parse(ev.data);
          if (msg && msg.error) showError("live view: " + msg.error);
        } catch (e) { /* not JSON: ignore */ }
        return;
      }
      onFrame(ev.data);
    };
    sock.onclose = (ev) => {
      if (ws !== sock) return;
      ws = null;
      const wait = backoff;
      backoff = Math.min(BACKOFF_MAX_MS, backoff * 2);
      setConn("disconnected", "badge-bad");
      showFallback("Live view disconnected" + (ev.reason ? " (" + ev.reason + ")" : "") +
                   ": reconnecting in " + (wait / 1000).toFixed(1) + " s. The last frames stay on screen.");
      reconnectTimer = setTimeout(connect, wait);
    };
    sock.onerror = () => { /* onclose follows and schedules the reconnect */ };
  }

  // ---- status ---------------------------------------------------------------------
  function fmt(v) {
    if (v === null || v === undefined) return "—";
    if (typeof v === "number") return Number.isInteger(v) ? String(v) : v.toFixed(2);
    if (typeof v === "boolean") return v ? "yes" : "no";
    if (Array.isArray(v)) return v.map(fmt).join(" × ");
    if (typeof v === "object") {
      return Object.entries(v).map(([k, x]) => k + ": " + fmt(x)).join(", ") || "—";
    }
    return String(v);
  }

  function flagsText(v) {
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

  let tokenHintShown = false;
  let currentSource = null;
  let sourceBusy = false;

  function setSourceRadios(source) {
    currentSource = source;
    if (sourceBusy) return;
    for (const s of ["live", "virtual"]) $("source-" + s).checked = source === s;
  }

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
    add("frames", "frames", fmt(st.frames));
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
  }

  function hasFlags(v) {
    const t = flagsText(v);
    return t !== "none" && t !== "—";
  }

  let statusFailing = false;
  async function refreshStatus() {
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

  // ---- source switch --------------------------------------------------------------
  async function putSource(source) {
    sourceBusy = true;
    try {
      const r = await api("PUT", "/api/source", { source: source });
      sourceBusy = false;
      setSourceRadios(r && r.source ? r.source : source);
      return true;
    } catch (e) {
      sourceBusy = false;
      showError(e.message);
      setSourceRadios(currentSource);
      return false;
    }
  }

  // ---- captures -------------------------------------------------------------------
  function humanBytes(n) {
    if (typeof n !== "number") return "";
    if (n < 1024) return n + " B";
    if (n < 1048576) return (n / 1024).toFixed(0) + " KiB";
    return (n / 1048576).toFixed(1) + " MiB";
  }

  async function refreshCaptures() {
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

  // ---- virtual camera and verify --------------------------------------------------
  async function upload(ev) {
    ev.preventDefault();
    const btn = $("btn-upload");
    await action(btn, async () => {
      const l = $("upload-left").files[0], r = $("upload-right").files[0], s = $("upload-sbs").files[0];
      const form = new FormData();
      if (l && r) {
        form.append("left", l, l.name);
        form.append("right", r, r.name);
      } else if (s && !l && !r) {
        form.append("sbs", s, s.name);
      } else {
        throw new ApiError("choose a left and a right image, or one side-by-side image");
      }
      const res = await api("POST", "/api/virtual-camera", form);
      setSourceRadios(res && res.source ? res.source : "virtual");
      $("upload-info").textContent = "frame " + fmt(res.frame) + ", " + fmt(res.width) + "×" + fmt(res.height) +
                                     ", source " + fmt(res.source);
      const box = $("upload-result");
      box.dataset.frame = String(res.frame);
      await Promise.all(["left", "right"].map((side) => loadImage($("vc-result-" + side),
        bust("/api/virtual-camera/result/" + side + ".png"))));
      box.hidden = false;
    });
  }

  // Set an <img> src and wait until it has loaded; a failed load is an error.
  function loadImage(img, url) {
    return new Promise((resolve, reject) => {
      img.onload = () => { img.onload = img.onerror = null; img.dataset.loaded = url; resolve(); };
      img.onerror = () => {
        img.onload = img.onerror = null;
        reject(new ApiError("GET " + url.split("?")[0] + " failed to load"));
      };
      img.src = url;
    });
  }

  function renderVerify(res) {
    const box = $("verify-result");
    const yes = !!res.identical;
    const strong = $("verify-identical");
    strong.textContent = yes ? "yes — identical" : "no — differs";
    strong.className = yes ? "ok" : "bad";
    box.dataset.identical = String(yes);
    const tbody = $("verify-table").tBodies[0];
    const frag = document.createDocumentFragment();
    const row = (name, c, cls) => {
      const tr = document.createElement("tr");
      if (cls) tr.className = cls;
      tr.setAttribute("data-testid", "verify-row-" + name);
      const psnr = c.psnr_db === null || c.psnr_db === undefined ? "∞" : fmt(c.psnr_db);
      const share = typeof c.share === "number" ? (c.share * 100).toFixed(3) + " %" : fmt(c.share);
      for (const cell of [name, fmt(c.differing), share, fmt(c.max_diff), psnr]) {
        const td = document.createElement("td");
        td.textContent = cell;
        tr.append(td);
      }
      frag.append(tr);
    };
    for (const [name, c] of Object.entries(res.channels || {})) row(name, c, c.differing ? "bad" : "");
    row("all", res, "total");
    tbody.replaceChildren(frag);
    const where = $("verify-where");
    const parts = [];
    for (const [cam, r] of Object.entries(res.regions || {})) {
      if (r) parts.push(cam + " camera: x " + r.x0 + "–" + r.x1 + ", y " + r.y0 + "–" + r.y1);
    }
    const first = res.first_difference;
    if (first) parts.unshift("first at (" + first.x + ", " + first.y + ")");
    where.textContent = parts.length ? "differences: " + parts.join("; ") : "";
    where.hidden = !parts.length;
    box.hidden = false;
    return loadImage($("verify-difference"), bust("/api/verify/difference.png"));
  }

  async function verify() {
    const btn = $("btn-verify");
    await action(btn, async () => {
      const res = await api("POST", "/api/verify");
      await renderVerify(res);
    });
  }

  // ---- camera sensors (GET/PUT /api/cameras) ---------------------------------------
  // The controls show the values in use of the chosen camera ("both": the left one, else the
  // right). A change sends only that field (+ "camera") as PUT; the slider is debounced
  // (CAMERA_DEBOUNCE_MS). The answer (the values now in use) is shown; errors go to #messages.
  const CAMERA_DEBOUNCE_MS = 200;
  let cameraState = null;      // the last GET/PUT body
  let cameraPending = {};      // fields waiting for the debounce timer
  let cameraTimer = null;
  let cameraInFlight = 0;

  function cameraShown(state) {
    if (!state) return null;
    const target = $("camera-target").value;
    if (target === "left" || target === "right") return state[target];
    return state.left || state.right || null;
  }

  function renderCameras(state) {
    cameraState = state;
    const v = cameraShown(state);
    const ids = ["camera-exposure", "camera-exposure-range", "camera-gain", "camera-gain-range",
                 "camera-aec", "camera-agc", "camera-flip-h", "camera-flip-v", "camera-test-pattern"];
    for (const id of ids) $(id).disabled = !v;
    const health = state && state.health ? state.health : {};
    const hel = $("camera-health");
    const bad = [];
    for (const c of ["left", "right"]) {
      const h = health[c];
      if (h && h.error) bad.push(c + ": " + h.error);
    }
    if (health.error) bad.push(health.error);
    hel.textContent = bad.length ? bad.join("; ") : (health.ok ? "sensors ok" : "");
    hel.className = "camera-health" + (bad.length ? " bad" : "");
    const form = $("camera-form");
    form.dataset.updated = String(Date.now());
    if (!v) return;
    // Do not overwrite a value the user is still editing (pending debounce).
    if (!("exposure_us" in cameraPending) && typeof v.exposure_us === "number") {
      const us = Math.round(v.exposure_us);
      $("camera-exposure").value = String(us);
      $("camera-exposure-range").value = String(us);
    }
    if (!("gain" in cameraPending) && typeof v.gain === "number") {
      const g = Math.round(v.gain * 10) / 10;
      $("camera-gain").value = String(g);
      $("camera-gain-range").value = String(g);
    }
    $("camera-aec").checked = !!v.aec;
    $("camera-agc").checked = !!v.agc;
    $("camera-flip-h").checked = !!v.flip_h;
    $("camera-flip-v").checked = !!v.flip_v;
    const tp = v.test_pattern || "off";
    const sel = $("camera-test-pattern");
    if (![...sel.options].some((o) => o.value === tp)) {
      const opt = document.createElement("option");
      opt.value = opt.textContent = tp;
      sel.append(opt);
    }
    sel.value = tp;
    form.dataset.exposure = String(v.exposure_us);
  }

  async function loadCameras() {
    try {
      renderCameras(await api("GET", "/api/cameras"));
    } catch (e) {
      showError(e.message);
    }
  }

  async function flushCameras() {
    if (cameraTimer) { clearTimeout(cameraTimer); cameraTimer = null; }
    const fields = cameraPending;
    cameraPending = {};
    if (!Object.keys(fields).length) return;
    const body = Object.assign({ camera: $("camera-target").value }, fields);
    const form = $("camera-form");
    cameraInFlight += 1;
    form.dataset.busy = "1";
    try {
      renderCameras(await api("PUT", "/api/cameras", body));
      form.dataset.applied = JSON.stringify(fields);
    } catch (e) {
      showError(e.message);
      await loadCameras();  // show what is really in use
    } finally {
      cameraInFlight -= 1;
      if (!cameraInFlight) delete form.dataset.busy;
    }
  }

  function queueCamera(fields, debounce) {
    Object.assign(cameraPending, fields);
    if (cameraTimer) clearTimeout(cameraTimer);
    cameraTimer = null;
    if (debounce) cameraTimer = setTimeout(flushCameras, CAMERA_DEBOUNCE_MS);
    else flushCameras();
  }

  function initCameras() {
    const pairs = [["camera-exposure", "camera-exposure-range", "exposure_us", (x) => Math.round(x)],
                   ["camera-gain", "camera-gain-range", "gain", (x) => Math.round(x * 10) / 10]];
    for (const [numId, rangeId, key, norm] of pairs) {
      const num = $(numId), range = $(rangeId);
      const send = (text, debounce) => {
        const n = Number(text);
        if (text === "" || !Number.isFinite(n)) return;
        queueCamera({ [key]: norm(n) }, debounce);
      };
      range.addEventListener("input", () => { num.value = range.value; send(range.value, true); });
      range.addEventListener("change", () => { num.value = range.value; send(range.value, false); });
      num.addEventListener("input", () => { range.value = num.value; send(num.value, true); });
      num.addEventListener("change", () => { range.value = num.value; send(num.value, false); });
    }
    const checks = [["camera-aec", "aec"], ["camera-agc", "agc"], ["camera-flip-h", "flip_h"],
                    ["camera-flip-v", "flip_v"]];
    for (const [id, key] of checks) {
      $(id).addEventListener("change", (ev) => queueCamera({ [key]: ev.target.checked }, false));
    }
    $("camera-test-pattern").addEventListener("change", (ev) => {
      const v = ev.target.value;
      queueCamera({ test_pattern: v === "off" ? null : v }, false);
    });
    $("camera-target").addEventListener("change", () => { if (cameraState) renderCameras(cameraState); loadCameras(); });
    loadCameras();
  }

  // ---- calibration panel (issue 4) ---------------------------------------------------
  // While the panel is open and "show corners" is ticked, GET /api/calibration/corners is
  // polled (one request at a time) and the corners are drawn over the raw views. Pairs,
  // coverage, compute, figures and apply go through the /api/calibration/* endpoints.
  const SVG_NS = "http://www.w3.org/2000/svg";
  const CORNER_PAUSE_MS = 300;  // a detection costs tens of ms of the board's CPU
  let cornersRunning = false;
  let cornersFailing = false;
  let calibSession = null;
  let calibCandidate = null;

  function svgEl(name, attrs) {
    const el = document.createElementNS(SVG_NS, name);
    for (const [k, v] of Object.entries(attrs || {})) el.setAttribute(k, String(v));
    return el;
  }

  function setViewBox(svg, size) {
    if (Array.isArray(size) && size.length === 2) svg.setAttribute("viewBox", "0 0 " + size[0] + " " + size[1]);
  }

  function drawCorners(side, points, size) {
    const svg = $("corners-" + side);
    setViewBox(svg, size);
    const frag = document.createDocumentFragment();
    if (Array.isArray(points) && points.length) {
      frag.append(svgEl("polyline", { points: points.map((p) => p[0] + "," + p[1]).join(" "), class: "found" }));
      frag.append(svgEl("circle", { cx: points[0][0], cy: points[0][1], r: 6, class: "found" }));
      for (const p of points) frag.append(svgEl("circle", { cx: p[0], cy: p[1], r: 2.5, class: "found" }));
    }
    svg.replaceChildren(frag);
    svg.dataset.corners = String(Array.isArray(points) ? points.length : 0);
  }

  function cornersWanted() { return $("calib").open && $("calib-live").checked; }

  async function cornersLoop() {
    if (cornersRunning) return;
    cornersRunning = true;
    const state = $("calib-live-state");
    try {
      while (cornersWanted()) {
        try {
          const res = await api("GET", "/api/calibration/corners");
          cornersFailing = false;
          if (!cornersWanted()) break;
          drawCorners("left", res.left, res.image_size);
          drawCorners("right", res.right, res.image_size);
          const where = res.found ? "board " + res.pattern + " found in both views" :
            (res.left ? "found in the left view only" : res.right ? "found in the right view only" :
             "board " + res.pattern + " not found");
          state.textContent = where + " (frame #" + res.frame + ", " + fmt(res.ms) + " ms)";
          state.className = "calib-live-state" + (res.found ? " ok" : "");
          state.dataset.found = String(!!res.found);
          state.dataset.frame = String(res.frame);
        } catch (e) {
          state.textContent = e.message;
          state.className = "calib-live-state bad";
          state.dataset.found = "false";
          if (!cornersFailing) showError(e.message);
          cornersFailing = true;
          await new Promise((r) => setTimeout(r, 1000));
        }
        await new Promise((r) => setTimeout(r, CORNER_PAUSE_MS));
      }
    } finally {
      cornersRunning = false;
      for (const side of ["left", "right"]) drawCorners(side, null, null);
      if (!cornersWanted()) { state.textContent = "—"; state.className = "calib-live-state"; }
    }
  }

  function renderCoverage(session) {
    const size = session.image_size;
    for (const side of ["left", "right"]) {
      const svg = $("calib-coverage-" + side);
      setViewBox(svg, size);
      const frag = document.createDocumentFragment();
      for (const pair of session.pairs) {
        const pts = pair.corners && pair.corners[side];
        if (!Array.isArray(pts) || pts.length < 4) continue;
        frag.append(svgEl("polygon", { points: hull(pts).map((p) => p[0] + "," + p[1]).join(" ") }));
      }
      svg.replaceChildren(frag);
      const share = session.coverage ? session.coverage[side] : 0;
      const el = $("calib-coverage-" + side + "-share");
      el.textContent = Math.round(100 * (share || 0)) + " %";
      el.dataset.share = String(share || 0);
    }
  }

  // Convex hull (monotone chain) of [x, y] points: the board's outline as the corners show it.
  function hull(points) {
    const p = points.slice().sort((a, b) => a[0] - b[0] || a[1] - b[1]);
    const cross = (o, a, b) => (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    const lower = [], upper = [];
    for (const q of p) {
      while (lower.length >= 2 && cross(lower[lower.length - 2], lower[lower.length - 1], q) <= 0) lower.pop();
      lower.push(q);
    }
    for (const q of p.slice().reverse()) {
      while (upper.length >= 2 && cross(upper[upper.length - 2], upper[upper.length - 1], q) <= 0) upper.pop();
      upper.push(q);
    }
    return lower.slice(0, -1).concat(upper.slice(0, -1));
  }

  // "#n": the pair's place in the stored list (oldest first), the same number everywhere.
  function pairLabel(id) {
    const i = calibSession ? calibSession.pairs.findIndex((p) => p.id === id) : -1;
    return i < 0 ? "(deleted)" : "#" + (i + 1);
  }

  function renderSession(session) {
    calibSession = session;
    const st = session.settings || {};
    const focused = document.activeElement;
    if (focused !== $("calib-pattern")) $("calib-pattern").value = st.pattern || "";
    if (focused !== $("calib-square")) $("calib-square").value = st.square_mm === undefined ? "" : String(st.square_mm);
    if (focused !== $("calib-alpha")) $("calib-alpha").value = st.alpha === undefined ? "" : String(st.alpha);
    const count = $("calib-count");
    count.textContent = String(session.count);
    count.dataset.count = String(session.count);
    $("calib-folder").textContent = session.folder ? "in " + session.folder : "";
    renderCoverage(session);
    const list = $("calib-pairs");
    const frag = document.createDocumentFragment();
    session.pairs.forEach((pair, i) => {
      const li = document.createElement("li");
      li.setAttribute("data-testid", "calib-pair");
      li.dataset.id = pair.id;
      if (calibCandidate && calibCandidate.worst_pair === pair.id) {
        li.className = "worst";
        li.title = "the largest row error in the computed calibration";
      }
      const info = document.createElement("div");
      info.className = "cap-info";
      const name = document.createElement("code");
      name.textContent = "#" + (i + 1) + " " + pair.id;
      const meta = document.createElement("small");
      meta.textContent = [pair.pattern, pair.frame !== undefined ? "frame " + pair.frame : "", pair.error || ""]
        .filter(Boolean).join(" · ");
      info.append(name, meta);
      const del = document.createElement("button");
      del.type = "button";
      del.className = "danger";
      del.textContent = "delete";
      del.setAttribute("data-testid", "calib-pair-delete");
      del.addEventListener("click", () => action(del, async () => {
        await api("DELETE", "/api/calibration/pairs/" + encodeURIComponent(pair.id));
        await refreshSession();
      }));
      li.append(info, del);
      frag.append(li);
    });
    list.replaceChildren(frag);
    $("btn-calib-clear").disabled = !session.count;
    if (calibCandidate) renderPairTable(calibCandidate);
    const progress = session.progress || {};
    if (progress.state === "running" && !computeWatching) watchCompute();
  }

  async function refreshSession() { renderSession(await api("GET", "/api/calibration/session")); }

  async function putCalibSettings(fields) {
    try {
      renderSession(await api("PUT", "/api/calibration/session", fields));
    } catch (e) {
      showError(e.message);
      if (calibSession) renderSession(calibSession);  // back to the settings in use
    }
  }

  function fixed(v, digits) { return typeof v === "number" ? v.toFixed(digits) : "—"; }

  function renderCandidate(cand) {
    calibCandidate = cand;
    const r = cand.report;
    const box = $("calib-result");
    const dl = $("calib-figures");
    const rows = [
      ["pairs", r.pairs_used + " used, " + r.pairs_rejected + " rejected"],
      ["rms", fixed(r.rms, 3) + " px reprojection (RMS)"],
      ["row_error", fixed(r.row_error_mean, 3) + " px mean, " + fixed(r.row_error_max, 3) + " px max"],
      ["rows", r.rows_needed + " of " + r.lb_rows + " line-buffer rows" + (cand.fits ? "" : " — does NOT fit")],
      ["baseline", fixed(r.baseline_m * 1000, 2) + " mm"],
      ["left", "fx " + fixed(r.left.fx, 1) + " fy " + fixed(r.left.fy, 1) + " cx " + fixed(r.left.cx, 1) + " cy " + fixed(r.left.cy, 1)],
      ["right", "fx " + fixed(r.right.fx, 1) + " fy " + fixed(r.right.fy, 1) + " cx " + fixed(r.right.cx, 1) + " cy " + fixed(r.right.cy, 1)],
      ["id", cand.id],
    ];
    const frag = document.createDocumentFragment();
    for (const [key, value] of rows) {
      const dt = document.createElement("dt");
      dt.textContent = key.replace("_", " ");
      const dd = document.createElement("dd");
      dd.textContent = value;
      dd.setAttribute("data-testid", "calib-figure-" + key);
      if (key === "rows" && !cand.fits) dd.className = "bad";
      frag.append(dt, dd);
    }
    dl.replaceChildren(frag);

    renderPairTable(cand);
    const select = $("calib-preview-pair");
    if (cand.worst_pair && [...select.options].some((o) => o.value === cand.worst_pair)) select.value = cand.worst_pair;
    $("btn-calib-apply").disabled = !cand.fits;
    $("btn-calib-apply").title = cand.fits ? "" : "this calibration needs more line-buffer rows than the core has";
    box.dataset.id = cand.id;
    box.hidden = false;
    return showPreview();
  }

  function renderPairTable(cand) {
    const r = cand.report;
    const worstRms = Math.max(1e-9, ...r.pairs.filter((p) => p.used).map((p) => p.rms));
    const tbody = $("calib-pair-table").tBodies[0];
    const tf = document.createDocumentFragment();
    const select = $("calib-preview-pair");
    const chosen = select.value;
    const options = document.createDocumentFragment();
    for (const p of r.pairs) {
      const label = pairLabel(p.id);
      const gone = label === "(deleted)";
      const tr = document.createElement("tr");
      tr.setAttribute("data-testid", "calib-pair-row");
      const cells = p.used ?
        [label, fixed(p.rms, 3), fixed(p.row_error_mean, 3) + " / " + fixed(p.row_error_max, 3)] :
        [label, "rejected", p.reason];
      for (const c of cells) {
        const td = document.createElement("td");
        td.textContent = c;
        tr.append(td);
      }
      const barCell = document.createElement("td");
      if (p.used) {
        const track = document.createElement("div");
        track.className = "bar-track";
        const bar = document.createElement("div");
        bar.className = "bar";
        bar.style.width = Math.round(100 * p.rms / worstRms) + "%";
        track.append(bar);
        barCell.append(track);
      } else {
        tr.className = "bad";
      }
      if (!gone) {
        const drop = document.createElement("button");
        drop.type = "button";
        drop.className = "danger drop";
        drop.textContent = "×";
        drop.title = "delete this pair (then compute again)";
        drop.setAttribute("aria-label", "delete pair " + label);
        drop.setAttribute("data-testid", "calib-pair-row-delete");
        drop.addEventListener("click", () => action(drop, async () => {
          await api("DELETE", "/api/calibration/pairs/" + encodeURIComponent(p.id));
          await refreshSession();
        }));
        barCell.append(drop);
      }
      tr.append(barCell);
      if (p.id === cand.worst_pair) tr.classList.add("worst");
      tr.title = p.id || p.name;
      tf.append(tr);
      if (p.used && !gone) {
        const opt = document.createElement("option");
        opt.value = p.id;
        opt.textContent = label + (p.id === cand.worst_pair ? " (largest row error)" : "");
        options.append(opt);
      }
    }
    tbody.replaceChildren(tf);
    select.replaceChildren(options);
    if ([...select.options].some((o) => o.value === chosen)) select.value = chosen;
  }

  function showPreview() {
    const pair = $("calib-preview-pair").value;
    if (!pair) return Promise.resolve();
    const url = bust("/api/calibration/candidate/rectified.png?pair=" + encodeURIComponent(pair));
    $("calib-rectified-link").href = url;
    return loadImage($("calib-rectified"), url);
  }

  // Progress of a compute, whichever tab started it; when it is done the candidate is shown.
  let computeWatching = false;
  async function watchCompute() {
    if (computeWatching) return;
    computeWatching = true;
    const bar = $("calib-progress");
    const text = $("calib-progress-text");
    bar.hidden = false;
    bar.removeAttribute("value");
    try {
      for (;;) {
        let p;
        try { p = await api("GET", "/api/calibration/compute"); } catch (e) { p = { state: "unknown" }; }
        if (p.state === "running") {
          if (p.total) {
            bar.max = p.total;
            bar.value = p.done;
            text.textContent = p.stage + " " + p.done + " / " + p.total;
          } else {
            text.textContent = "computing…";
          }
        } else {
          if (p.state === "failed") text.textContent = "failed: " + p.error;
          if (p.state === "done") await loadCandidate();
          return;
        }
        await new Promise((r) => setTimeout(r, 250));
      }
    } finally {
      computeWatching = false;
      bar.hidden = true;
    }
  }

  async function loadCandidate() {
    let cand;
    try {
      cand = await api("GET", "/api/calibration/candidate");
    } catch (e) {
      if (e instanceof ApiError && e.message.includes("→ 404")) return;  // none computed yet
      throw e;
    }
    if (!calibCandidate || calibCandidate.id !== cand.id || calibCandidate.computed_at !== cand.computed_at) {
      $("calib-progress-text").textContent = "computed from " + cand.report.pairs_used + " pairs";
      await renderCandidate(cand);
    }
  }

  async function computeCalibration() {
    const btn = $("btn-calib-compute");
    await action(btn, async () => {
      $("calib-progress-text").textContent = "computing…";
      const watching = watchCompute();
      try {
        const cand = await api("POST", "/api/calibration/compute");
        $("calib-progress-text").textContent = "computed from " + cand.report.pairs_used + " pairs";
        await renderCandidate(cand);
        await refreshSession();
      } catch (e) {
        $("calib-progress-text").textContent = "";
        throw e;
      } finally {
        await watching;
      }
    });
  }

  function typing(target) {
    return target instanceof HTMLElement && (target.isContentEditable ||
      ["INPUT", "SELECT", "TEXTAREA", "BUTTON"].includes(target.tagName));
  }

  function initCalibration() {
    const details = $("calib");
    details.addEventListener("toggle", () => {
      if (details.open) {
        action(null, async () => { await refreshSession(); await loadCandidate(); });
        cornersLoop();
      }
    });
    // Space or C captures a pair while the panel is open: the person holding the board may be
    // far from the mouse (a wireless keyboard or presenter remote sends these).
    document.addEventListener("keydown", (ev) => {
      if (!details.open || ev.repeat || ev.ctrlKey || ev.metaKey || ev.altKey || typing(ev.target)) return;
      if (ev.key === " " || ev.key === "c" || ev.key === "C") {
        ev.preventDefault();
        const btn = $("btn-calib-pair");
        if (!btn.disabled) btn.click();
      }
    });
    $("calib-live").addEventListener("change", () => cornersLoop());
    $("calib-pattern").addEventListener("change", (ev) => putCalibSettings({ pattern: ev.target.value.trim() }));
    const numberSetting = (id, key, what) => $(id).addEventListener("change", (ev) => {
      const text = ev.target.value.trim();
      if (text === "" || !Number.isFinite(Number(text))) {
        showError("give the " + what + " as a number");
        if (calibSession) renderSession(calibSession);
        return;
      }
      putCalibSettings({ [key]: Number(text) });
    });
    numberSetting("calib-square", "square_mm", "square size in millimetres");
    numberSetting("calib-alpha", "alpha", "alpha (0 to 1)");
    $("btn-calib-pair").addEventListener("click", (ev) => action(ev.currentTarget, async () => {
      const res = await api("POST", "/api/calibration/pairs");
      renderSession(res);
      showMessage("pair " + res.count + " stored", "info");
    }));
    $("btn-calib-clear").addEventListener("click", (ev) => action(ev.currentTarget, async () => {
      if (!window.confirm("Delete every stored calibration pair?")) return;
      await api("DELETE", "/api/calibration/pairs");
      await refreshSession();
    }));
    $("btn-calib-compute").addEventListener("click", computeCalibration);
    $("calib-preview-pair").addEventListener("change", () => action(null, showPreview));
    $("btn-calib-apply").addEventListener("click", (ev) => action(ev.currentTarget, async () => {
      if (!calibCandidate) throw new ApiError("compute a calibration first");
      const res = await api("POST", "/api/calibration/apply", { id: calibCandidate.id });
      $("calib-result").dataset.applied = res.id;
      showMessage("calibration " + res.id + " is now programmed in the core and saved to " + res.file, "info");
    }));
  }

  // ---- wiring ---------------------------------------------------------------------
  function init() {
    $("btn-capture").addEventListener("click", (ev) => action(ev.currentTarget, async () => {
      const res = await api("POST", "/api/captures");
      showMessage("captured " + (res && res.id ? res.id : ""), "info");
      await refreshCaptures();
    }));
    for (const s of ["live", "virtual"]) {
      $("source-" + s).addEventListener("change", (ev) => { if (ev.target.checked) putSource(s); });
    }
    $("upload-form").addEventListener("submit", upload);
    $("btn-verify").addEventListener("click", verify);
    window.addEventListener("beforeunload", () => { if (ws) ws.close(); });

    connect();
    refreshStatus();
    action(null, refreshCaptures);
    initCameras();
    initCalibration();
    document.body.dataset.ready = "1";
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init); else init();
})();
