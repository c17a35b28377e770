// The viewer page: the image mode (upload, detect, draw, inspect, download) and the tabs.
// Plain ES modules served by the service; nothing is loaded from anywhere else.

import {
  authHeaders, hideMessage, networkProblem, problem, responseProblem, setToken, showInfo,
  showProblem, token,
} from "./api.js";
import { chainColour, chainStats, drawDetection, drawPlaceholder, hover } from "./draw.js";
import { LiveMode } from "./live.js";

const $ = (id) => document.getElementById(id);

const state = {
  config: null,
  image: null, // the File being shown
  mask: null,
  bitmap: null, // the image decoded by the browser (null: it could not decode it)
  detection: null,
  detectionText: "",
  jsonUrl: null,
  highlight: null,
  busy: false,
};

const canvas = $("image-canvas");
const context = canvas.getContext("2d");
const message = $("image-message");
const tooltip = $("image-tooltip");

// -- configuration and the token ---------------------------------------------------------------

async function loadConfig() {
  try {
    const response = await fetch("/viewer/config", { cache: "no-store" });
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    state.config = await response.json();
  } catch (error) {
    showProblem(message, networkProblem(error));
    state.config = { token_required: false, zenoh: false, defaults: { segment_length: 10 }, segmentation_methods: ["auto"] };
  }
  const { defaults, segmentation_methods: methods } = state.config;
  $("segment-length").value = defaults.segment_length;
  const select = $("segmentation");
  select.replaceChildren(...methods.map((method) => new Option(method, method)));
  select.value = defaults.segmentation || methods[0];
  $("hsv-low").value = (defaults.hsv_low || [0, 0, 60]).join(",");
  $("hsv-high").value = (defaults.hsv_high || [179, 255, 255]).join(",");
  if (state.config.token_required) askForToken(!token());
}

function askForToken(focus) {
  const form = $("token-form");
  form.hidden = false;
  $("token").value = token();
  if (focus) $("token").focus();
}

$("token-form").addEventListener("submit", (event) => {
  event.preventDefault();
  setToken($("token").value.trim());
  hideMessage(message);
  if (state.image) detect();
  live.refreshCameras();
});

// -- choosing files ------------------------------------------------------------------------------

function describeFiles() {
  const names = [];
  if (state.image) names.push(`image: ${state.image.name || "(dropped)"}`);
  if (state.mask) names.push(`mask: ${state.mask.name}`);
  $("file-names").textContent = names.length ? names.join(", ") : "No image chosen";
}

async function chooseImage(file) {
  state.image = file;
  if (state.bitmap) state.bitmap.close();
  state.bitmap = null;
  try {
    state.bitmap = await createImageBitmap(file);
  } catch {
    state.bitmap = null; // the service says why, below
  }
  describeFiles();
  await detect();
}

$("image-file").addEventListener("change", (event) => {
  const [file] = event.target.files;
  if (file) chooseImage(file);
});
$("mask-file").addEventListener("change", (event) => {
  state.mask = event.target.files[0] || null;
  describeFiles();
  if (state.image) detect();
});

const dropZone = $("drop-zone");
for (const target of [dropZone, canvas]) {
  target.addEventListener("dragover", (event) => {
    event.preventDefault();
    dropZone.classList.add("over");
  });
  target.addEventListener("dragleave", () => dropZone.classList.remove("over"));
  target.addEventListener("drop", (event) => {
    event.preventDefault();
    dropZone.classList.remove("over");
    const files = [...event.dataTransfer.files];
    if (files.length) chooseImage(files[0]);
    if (files.length > 1) {
      state.mask = files[1]; // a second file dropped with it: its mask
      describeFiles();
    }
  });
}

$("segmentation").addEventListener("change", () => {
  $("hsv-fields").hidden = $("segmentation").value !== "hsv";
});

// -- detecting -------------------------------------------------------------------------------------

function query() {
  const params = new URLSearchParams();
  params.set("segment_length", $("segment-length").value);
  const count = $("expected-count").value.trim();
  if (count) params.set("expected_count", count);
  params.set("segmentation", $("segmentation").value);
  if ($("segmentation").value === "hsv") {
    params.set("hsv_low", $("hsv-low").value.replace(/\s+/g, ""));
    params.set("hsv_high", $("hsv-high").value.replace(/\s+/g, ""));
  }
  return params;
}

// The request body: the image alone (its own type, so a wrong type gets the service's 415),
// or a form with the mask beside it.
function body() {
  if (!state.mask) {
    return { body: state.image, type: state.image.type || "application/octet-stream" };
  }
  const form = new FormData();
  form.append("image", state.image, state.image.name || "image");
  form.append("mask", state.mask, state.mask.name || "mask");
  return { body: form, type: null };
}

async function post(path) {
  const { body: content, type } = body();
  const headers = authHeaders();
  if (type) headers["Content-Type"] = type;
  return fetch(`${path}?${query()}`, { method: "POST", body: content, headers });
}

function sizeCanvas(width, height) {
  if (canvas.width !== width) canvas.width = width;
  if (canvas.height !== height) canvas.height = height;
}

function redraw() {
  const detection = state.detection;
  if (!detection) return;
  sizeCanvas(detection.width, detection.height);
  if (state.bitmap) {
    context.drawImage(state.bitmap, 0, 0, detection.width, detection.height);
  } else {
    context.fillStyle = "#11151c";
    context.fillRect(0, 0, canvas.width, canvas.height);
  }
  drawDetection(context, detection, state.highlight);
}

function showFailure(found) {
  showProblem(message, found);
  if (found.status === 401) askForToken(true);
  if (state.bitmap) sizeCanvas(state.bitmap.width, state.bitmap.height);
  const lines = [found.status ? `${found.status} · ${found.title}` : found.title];
  if (found.detail) lines.push(found.detail);
  drawPlaceholder(context, lines, state.bitmap);
  clearResult();
}

function clearResult() {
  state.detection = null;
  $("chain-count").textContent = "";
  $("summary-text").textContent = "No result.";
  $("chains-table").querySelector("tbody").replaceChildren();
  $("timings-table").querySelector("tbody").replaceChildren();
  $("download-json").hidden = true;
  $("download-labels").hidden = true;
}

async function detect() {
  if (!state.image || state.busy) return;
  if (!$("detect-form").reportValidity()) return;
  state.busy = true;
  $("detect-button").disabled = true;
  showInfo(message, "Detecting…");
  const started = performance.now();
  try {
    const response = await post("/v1/detect");
    if (!response.ok) {
      showFailure(await responseProblem(response));
      return;
    }
    const text = await response.text();
    let detection;
    try {
      detection = JSON.parse(text);
    } catch {
      showFailure(problem(500, "the service's answer is not JSON"));
      return;
    }
    hideMessage(message);
    showResult(detection, text, performance.now() - started);
  } catch (error) {
    showFailure(networkProblem(error));
  } finally {
    state.busy = false;
    $("detect-button").disabled = false;
  }
}

function stem() {
  const name = (state.image && state.image.name) || "image";
  return name.replace(/\.[^.]*$/, "") || "image";
}

function showResult(detection, text, roundTripMs) {
  state.detection = detection;
  state.detectionText = text;
  state.highlight = null;
  redraw();
  const chains = detection.chains.length;
  $("chain-count").textContent = String(chains);
  const crossings = (detection.crossings || []).length;
  $("summary-text").textContent =
    `chain${chains === 1 ? "" : "s"}, ${crossings} crossing${crossings === 1 ? "" : "s"} · ` +
    `${detection.width}×${detection.height} px · segment length ${detection.segment_length} px`;
  fillChainTable(detection);
  fillTimings(detection.timings_ms || {}, roundTripMs);
  if (state.jsonUrl) URL.revokeObjectURL(state.jsonUrl);
  state.jsonUrl = URL.createObjectURL(new Blob([text], { type: "application/json" }));
  const link = $("download-json");
  link.href = state.jsonUrl;
  link.download = `${stem()}.json`;
  link.hidden = false;
  $("download-labels").hidden = false;
}

function cell(text) {
  const td = document.createElement("td");
  td.textContent = text;
  return td;
}

function fillChainTable(detection) {
  const rows = detection.chains.map((chain) => {
    const stats = chainStats(chain);
    const row = document.createElement("tr");
    row.dataset.chain = String(chain.id);
    const id = cell(String(chain.id));
    const swatch = document.createElement("span");
    swatch.className = "swatch";
    swatch.style.background = chainColour(chain.id);
    id.prepend(swatch);
    row.append(
      id,
      cell(stats.length.toFixed(1)),
      cell(String(stats.joints)),
      cell(`${(stats.inferredShare * 100).toFixed(0)} %`),
      cell(stats.radius.toFixed(1)),
    );
    row.addEventListener("mouseenter", () => setHighlight(chain.id));
    row.addEventListener("mouseleave", () => setHighlight(null));
    return row;
  });
  $("chains-table").querySelector("tbody").replaceChildren(...rows);
}

const STAGES = ["segmentation", "skeleton", "contours", "fitting", "pruning", "merging", "total"];

function fillTimings(timings, roundTripMs) {
  const rows = STAGES.map((stage) => {
    const row = document.createElement("tr");
    row.append(cell(stage), cell(Number(timings[stage] || 0).toFixed(1)));
    return row;
  });
  const trip = document.createElement("tr");
  trip.append(cell("round trip (page)"), cell(roundTripMs.toFixed(1)));
  rows.push(trip);
  $("timings-table").querySelector("tbody").replaceChildren(...rows);
}

function setHighlight(id) {
  if (state.highlight === id) return;
  state.highlight = id;
  for (const row of $("chains-table").querySelectorAll("tbody tr")) {
    row.classList.toggle("highlight", row.dataset.chain === String(id));
  }
  redraw();
}

canvas.addEventListener("mousemove", (event) => setHighlight(hover(canvas, tooltip, state.detection, event)));
canvas.addEventListener("mouseleave", () => {
  tooltip.hidden = true;
  setHighlight(null);
});

$("detect-form").addEventListener("submit", (event) => {
  event.preventDefault();
  detect();
});

$("download-labels").addEventListener("click", async () => {
  if (!state.image) return;
  const button = $("download-labels");
  button.disabled = true;
  try {
    const response = await post("/v1/detect/labels");
    if (!response.ok) {
      showProblem(message, await responseProblem(response));
      return;
    }
    const url = URL.createObjectURL(await response.blob());
    const link = document.createElement("a");
    link.href = url;
    link.download = `${stem()}.labels.png`;
    document.body.append(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10_000);
  } catch (error) {
    showProblem(message, networkProblem(error));
  } finally {
    button.disabled = false;
  }
});

// -- tabs ------------------------------------------------------------------------------------------

const live = new LiveMode({ onUnauthorized: () => askForToken(true) });

function selectTab(name) {
  for (const [tab, panel] of [["tab-image", "image-mode"], ["tab-live", "live-mode"]]) {
    const selected = panel === name;
    $(tab).setAttribute("aria-selected", String(selected));
    $(panel).hidden = !selected;
  }
  live.setVisible(name === "live-mode");
}

$("tab-image").addEventListener("click", () => selectTab("image-mode"));
$("tab-live").addEventListener("click", () => selectTab("live-mode"));

drawPlaceholder(context, ["Drop an image here, or choose one on the left"]);
await loadConfig();
live.configure(state.config);
if (location.hash === "#live") selectTab("live-mode");
document.body.dataset.ready = "true";
