// stereocam page: plain ES modules, no framework, no build step, no outside assets (the board has
// no internet). One module per panel; core.js holds what they share.
import { initCameras } from "./cameras.js";
import { initCalibration } from "./calibration.js";
import { initCaptures } from "./captures.js";
import { closeLive, connect } from "./live.js";
import { initSource } from "./source.js";
import { refreshStatus } from "./status.js";
import { initVirtual } from "./virtual.js";

function init() {
  initSource();
  initVirtual();
  window.addEventListener("beforeunload", closeLive);
  connect();
  refreshStatus();
  initCaptures();
  initCameras();
  initCalibration();
  document.body.dataset.ready = "1";
}

if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init); else init();
