// The stereo core's matcher registers (GET/PUT /api/stereo): one input per parameter, built from the
// daemon's answer (its limits are the core's build, read back), so no parameter is listed here.
// Apply sends only what changed; a refusal (422) says every problem and the core keeps its values.
import { $, api, showError, showInfo } from "./core.js";

let stereoState = null;  // the last GET/PUT body

function fieldId(name) { return "stereo-" + name.replace(/_/g, "-"); }

function buildFields(state) {
  const box = $("stereo-fields");
  box.replaceChildren();
  for (const [name, value] of Object.entries(state.params)) {
    const limit = state.limits[name] || {};
    const label = document.createElement("label");
    const input = document.createElement("input");
    input.id = fieldId(name);
    input.setAttribute("data-testid", fieldId(name));
    input.dataset.param = name;
    if (limit.type === "boolean") {
      label.className = "check";
      input.type = "checkbox";
      input.checked = !!value;
      label.append(input, " " + name.replace(/_/g, " "));
    } else {
      label.className = "row";
      input.type = "number";
      input.min = String(limit.min);
      input.max = String(limit.max);
      input.step = String(limit.multiple_of || 1);
      input.value = String(value);
      label.append(name.replace(/_/g, " ") + " (" + limit.min + " to " + limit.max + ")", input);
    }
    box.append(label);
  }
}

function render(state) {
  stereoState = state;
  const form = $("stereo-form");
  if (!state.present) {
    $("stereo-by").textContent = "The disparity is computed on the " + state.by +
      ": this bitstream has no stereo core, so there are no matcher registers to set.";
    form.hidden = true;
    return;
  }
  $("stereo-by").textContent = "The disparity comes from the fabric's " + state.by + ".";
  form.hidden = false;
  buildFields(state);
  form.dataset.updated = String(Date.now());
}

function changes() {
  const out = {};
  for (const input of $("stereo-fields").querySelectorAll("input[data-param]")) {
    const name = input.dataset.param;
    const value = input.type === "checkbox" ? input.checked : Number(input.value);
    if (value !== stereoState.params[name]) out[name] = value;
  }
  return out;
}

async function send(body) {
  if (!Object.keys(body).length) return;
  // Held while the PUT is out: its answer rebuilds the inputs, which would drop a value typed meanwhile.
  const set = $("stereo-set");
  set.disabled = true;
  try {
    render(await api("PUT", "/api/stereo", body));
    showInfo("Stereo matcher: " + Object.keys(body).join(", ") + " set.", "stereo");
  } catch (e) {
    showError(e, { explain: {
      422: (x) => "The stereo core would refuse that: " + x.detail + ".",
      409: (x) => x.detail + ".",
    } });
    await load();  // show what the core really holds
  } finally {
    set.disabled = false;
  }
}

async function load() {
  try {
    render(await api("GET", "/api/stereo"));
  } catch (e) {
    showError(e);
  }
}

export function initStereo() {
  $("stereo-apply").addEventListener("click", () => { if (stereoState) send(changes()); });
  $("stereo-defaults").addEventListener("click", () => {
    if (!stereoState) return;
    const body = {};
    for (const [k, v] of Object.entries(stereoState.defaults)) if (stereoState.params[k] !== v) body[k] = v;
    send(body);
  });
  load();
}
