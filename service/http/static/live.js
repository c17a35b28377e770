// The live mode: a camera's frames with their chains (or tracks) through the WebSocket
// /v1/live/<camera>. Each frame is acknowledged once drawn; the service sends at most two
// frames ahead of the acknowledgements and keeps only the newest meanwhile (latest wins),
// so a slow page sees fewer frames, never a growing backlog.

import {
  authHeaders, hideMessage, networkProblem, problem, responseProblem, showInfo, showProblem,
  token,
} from "./api.js";
import { drawDetection, drawPlaceholder, hover } from "./draw.js";

const $ = (id) => document.getElementById(id);
const decoder = new TextDecoder();
const FPS_WINDOW_MS = 2000;
const RECONNECT_MS = 2000;

export class LiveMode {
  constructor({ onUnauthorized }) {
    this.onUnauthorized = onUnauthorized;
    this.canvas = $("live-canvas");
    this.context = this.canvas.getContext("2d");
    this.message = $("live-message");
    this.tooltip = $("live-tooltip");
    this.socket = null;
    this.watching = null; // {camera, results} while the user wants to watch
    this.visible = false;
    this.poll = null;
    this.cameraCount = 0;
    this.resetStats();
    drawPlaceholder(this.context, ["Pick a camera and press Watch"]);
    $("live-form").addEventListener("submit", (event) => {
      event.preventDefault();
      this.start();
    });
    $("stop-button").addEventListener("click", () => this.stop());
    this.canvas.addEventListener("mousemove", (event) => {
      const id = hover(this.canvas, this.tooltip, this.detection, event);
      this.highlight = id;
    });
    this.canvas.addEventListener("mouseleave", () => {
      this.tooltip.hidden = true;
      this.highlight = null;
    });
  }

  configure(config) {
    this.config = config;
  }

  resetStats() {
    this.shown = 0;
    this.dropped = 0;
    this.droppedInPage = 0;
    this.droppedSlowLink = 0;
    this.lastSeq = null;
    this.times = [];
    this.detection = null;
    this.highlight = null;
    this.pending = null;
    this.drawing = false;
  }

  setVisible(visible) {
    this.visible = visible;
    clearTimeout(this.poll);
    if (visible) this.refreshCameras();
  }

  schedulePoll() {
    clearTimeout(this.poll);
    if (this.visible) this.poll = setTimeout(() => this.refreshCameras(), this.cameraCount ? 3000 : 1000);
  }

  async refreshCameras() {
    if (!this.visible) return;
    if (this.config && !this.config.zenoh) {
      showProblem(this.message, problem(503, "zenoh is off in this service (DLO_ZENOH=false): no cameras to watch"));
      return;
    }
    try {
      const response = await fetch("/v1/live/cameras", { headers: authHeaders(), cache: "no-store" });
      if (!response.ok) {
        const found = await responseProblem(response);
        if (!this.watching) showProblem(this.message, found);
        if (found.status === 401) {
          this.onUnauthorized();
          return; // asked again when a token is entered
        }
      } else {
        if (!this.watching && this.message.dataset.status) hideMessage(this.message);
        this.fillCameras((await response.json()).cameras);
      }
    } catch (error) {
      if (!this.watching) showProblem(this.message, networkProblem(error));
    }
    this.schedulePoll();
  }

  fillCameras(cameras) {
    const select = $("camera-select");
    const chosen = select.value;
    this.cameraCount = cameras.length;
    if (!cameras.length) {
      select.replaceChildren(new Option("(no camera seen yet)", ""));
      return;
    }
    select.replaceChildren(
      ...cameras.map((camera) => {
        const rate = camera.fps ? `${camera.fps.toFixed(1)} fps` : `last frame ${camera.last_frame_s.toFixed(0)} s ago`;
        return new Option(`${camera.camera} (${rate})`, camera.camera);
      }),
    );
    if (cameras.some((camera) => camera.camera === chosen)) select.value = chosen;
  }

  start() {
    const camera = $("camera-select").value;
    if (!camera) {
      showProblem(this.message, problem(0, "no camera publishes on dlo/<camera>/image yet"));
      return;
    }
    this.stop();
    this.watching = { camera, results: $("results-select").value };
    this.resetStats();
    this.updateStats();
    $("stop-button").disabled = false;
    this.connect();
  }

  stop() {
    this.watching = null;
    clearTimeout(this.reconnect);
    if (this.socket) {
      const socket = this.socket;
      this.socket = null;
      socket.onclose = null;
      socket.onmessage = null;
      socket.close(1000);
    }
    $("stop-button").disabled = true;
    $("live-status").textContent = "Stopped.";
  }

  connect() {
    const { camera, results } = this.watching;
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const url = `${scheme}://${location.host}/v1/live/${encodeURIComponent(camera)}?results=${results}`;
    const socket = new WebSocket(url);
    socket.binaryType = "arraybuffer";
    this.socket = socket;
    this.refused = null;
    showInfo(this.message, `Connecting to ${camera}…`);
    socket.onopen = () => {
      const value = token();
      if (value) socket.send(JSON.stringify({ type: "auth", token: value }));
    };
    socket.onmessage = (event) => {
      if (typeof event.data === "string") this.onText(event.data);
      else this.onFrame(event.data);
    };
    socket.onclose = (event) => this.onClose(socket, event);
  }

  onText(text) {
    let message;
    try {
      message = JSON.parse(text);
    } catch {
      return;
    }
    if (message.type === "hello") {
      showInfo(this.message, `Watching ${message.camera}: waiting for frames…`);
    } else if (message.type === "status") {
      this.showCameraFps(message.camera_fps);
      const last = message.last_frame_s;
      $("live-status").textContent =
        last == null ? "No frame from this camera yet." : `No new frame for ${last.toFixed(0)} s.`;
    } else if (message.type === "error") {
      this.refused = problem(message.status, message.detail, message.error);
      showProblem(this.message, this.refused);
      if (message.status === 401) this.onUnauthorized();
    }
  }

  onClose(socket, event) {
    if (socket !== this.socket) return;
    this.socket = null;
    if (!this.watching) return;
    if (event.code >= 4000) {
      const found = this.refused || problem(event.code - 4000, event.reason);
      showProblem(this.message, found);
      this.drawMessage([`${found.status} · ${found.title}`, found.detail]);
      this.watching = null;
      $("stop-button").disabled = true;
      return;
    }
    showProblem(this.message, problem(0, `the live connection closed (code ${event.code}); reconnecting`));
    this.reconnect = setTimeout(() => this.watching && this.connect(), RECONNECT_MS);
  }

  drawMessage(lines) {
    if (!this.shown) drawPlaceholder(this.context, lines.filter(Boolean));
  }

  ack() {
    if (this.socket && this.socket.readyState === WebSocket.OPEN) this.socket.send('{"type":"ack"}');
  }

  onFrame(buffer) {
    if (this.drawing) {
      if (this.pending) {
        this.droppedInPage += 1; // a newer one came while drawing: latest wins here too
        this.ack();
      }
      this.pending = buffer;
      return;
    }
    this.drawFrame(buffer);
  }

  async drawFrame(buffer) {
    this.drawing = true;
    try {
      await this.show(buffer);
    } catch (error) {
      showProblem(this.message, problem(0, `a frame could not be shown: ${error.message || error}`));
    } finally {
      this.ack();
      this.drawing = false;
      const next = this.pending;
      this.pending = null;
      if (next) this.drawFrame(next);
    }
  }

  async show(buffer) {
    const view = new DataView(buffer);
    const length = view.getUint32(0);
    const header = JSON.parse(decoder.decode(new Uint8Array(buffer, 4, length)));
    const resultStart = 4 + length;
    const imageStart = resultStart + header.result_bytes;
    const result = header.result_bytes
      ? JSON.parse(decoder.decode(new Uint8Array(buffer, resultStart, header.result_bytes)))
      : null;
    let bitmap = null;
    if (header.image_bytes) {
      const jpeg = new Blob([new Uint8Array(buffer, imageStart, header.image_bytes)], { type: "image/jpeg" });
      bitmap = await createImageBitmap(jpeg);
    }
    if (!this.watching) {
      if (bitmap) bitmap.close();
      return;
    }
    const detection = header.kind === "chains" || header.kind === "tracks" ? result : null;
    const width = bitmap ? bitmap.width : detection ? detection.width : this.canvas.width;
    const height = bitmap ? bitmap.height : detection ? detection.height : this.canvas.height;
    if (this.canvas.width !== width) this.canvas.width = width;
    if (this.canvas.height !== height) this.canvas.height = height;
    if (bitmap) {
      this.context.drawImage(bitmap, 0, 0);
      bitmap.close();
    } else {
      drawPlaceholder(this.context, [`frame ${header.seq}: ${header.image_error || "no image"}`]);
    }
    this.detection = detection;
    if (detection) drawDetection(this.context, detection, this.highlight);
    this.count(header);
    this.describe(header, result, detection);
  }

  count(header) {
    const now = performance.now();
    this.shown += 1;
    this.times.push(now);
    while (this.times.length && now - this.times[0] > FPS_WINDOW_MS) this.times.shift();
    if (this.lastSeq !== null && header.seq > this.lastSeq) this.dropped += header.seq - this.lastSeq - 1;
    this.lastSeq = header.seq;
    this.droppedSlowLink = header.dropped_slow_link || 0;
    this.showCameraFps(header.camera_fps);
    $("live-latency").textContent = header.latency_ms == null ? "–" : header.latency_ms.toFixed(0);
    $("live-pairing").textContent = header.pairing || (header.kind ? "–" : "no result");
    this.updateStats();
  }

  describe(header, result, detection) {
    const camera = header.camera;
    if (header.kind === "errors") {
      const detail = result ? `${result.error}: ${result.detail}` : "an error record";
      showProblem(this.message, problem(422, `frame ${header.frame_id ?? header.seq} of ${camera}: ${detail}`));
      $("live-chain-count").textContent = "–";
    } else if (!header.kind) {
      showInfo(this.message, `${camera}: no chains for its frames yet (no replica detects it, or none has answered).`);
      $("live-chain-count").textContent = "–";
    } else {
      if (!this.message.hidden) hideMessage(this.message);
      $("live-chain-count").textContent = String(detection.chains.length);
    }
    const what = header.kind === "tracks" ? "tracks" : "chains";
    const id = header.frame_id == null ? `#${header.seq}` : String(header.frame_id);
    $("live-status").textContent = `${camera} · frame ${id}${header.kind ? ` · ${what}` : ""}` +
      (header.replica ? ` · replica ${header.replica.slice(0, 8)}` : "");
  }

  showCameraFps(fps) {
    $("live-camera-fps").textContent = fps ? fps.toFixed(1) : "–";
  }

  updateStats() {
    const times = this.times;
    const fps = times.length > 1 ? ((times.length - 1) * 1000) / (times[times.length - 1] - times[0]) : 0;
    $("live-fps").textContent = times.length > 1 ? fps.toFixed(1) : "–";
    $("live-frames").textContent = String(this.shown);
    $("live-dropped").textContent = String(this.dropped);
    const detail = [];
    const undetected = this.dropped - this.droppedSlowLink - this.droppedInPage;
    if (undetected > 0) detail.push(`${undetected} not detected`);
    if (this.droppedSlowLink) detail.push(`${this.droppedSlowLink} for a slow link`);
    if (this.droppedInPage) detail.push(`${this.droppedInPage} while drawing`);
    $("live-dropped-detail").textContent = detail.length ? `(${detail.join(", ")})` : "";
  }
}
