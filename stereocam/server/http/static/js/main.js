// stereocam page: plain ES modules, no framework, no build step, no outside assets (the board has
// no internet). One module per panel; core.js holds what they share.
import { initCameras } from "./cameras.js";
import { initStereo } from "./stereo.js";
import { initCalibration } from "./calibration.js";
import { initCaptures } from "./captures.js";
import { closeLive, connect } from "./live.js";
import { initSource } from "./source.js";
import { initShortcuts } from "./shortcuts.js";
import { refreshStatus } from "./status.js";
import { initVirtual } from "./virtual.js";
import { initTools } from "./tools.js";
import { initFreeze } from "./freeze.js";
import { initRuler } from "./ruler.js";
import { initMessageNotice } from "./notice.js";
import { $, api, initSignIn, showError, showInfo, waitingForSignIn } from "./core.js";
import { init as initFit } from "./fit.js";
import { init as initRecordings } from "./recordings.js";
import { setSourceRadios } from "./source.js";

function init() {
  initSignIn();
  if (waitingForSignIn()) {
    // One state: the sign-in form; the views say they wait for it. Nothing else asks the daemon
    // (every read would be a 401); signing in reloads the page, which starts the rest.
    initShortcuts();
    document.body.dataset.ready = "1";
    return;
  }
  initSource();
  initVirtual();
  window.addEventListener("beforeunload", closeLive);
  connect();
  initTools();
  initFreeze();
  initRuler();
  refreshStatus();
  initCaptures();
  initCameras();
  initStereo();
  initCalibration();
  initShortcuts();
  initMessageNotice();
  const ctx = { api, showError, showInfo, $ };
  initFit(ctx);
  initRecordings({ ...ctx, onReplay: (res) => setSourceRadios(res && res.source ? res.source : "virtual") });
  document.body.dataset.ready = "1";
}

if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init); else init();
