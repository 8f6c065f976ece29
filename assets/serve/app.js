// illumnet serve: the page. Plain WebGL2, no library. The patches are one
// triangle list (/mesh.bin: positions and a patch id per vertex); each
// patch's radiance is one texel of a float texture, updated from the
// binary frames the server pushes, and tone mapped here (exposure, then
// the sRGB curve, as `render` writes PNGs). Changes of the light go to the
// server as JSON requests; every page sees the same state.
"use strict";

const $ = (id) => document.getElementById(id);
const state = { scene: null, radiance: null, patches: 0, exposure: 0, frame: 0, status: null, drawn: 0 };
window.illumnet = state; // for tests: the last radiance, status and frame drawn

// ---------------------------------------------------------------- WebGL

const canvas = $("canvas");
const gl = canvas.getContext("webgl2", { preserveDrawingBuffer: true });
const TEX_W = 2048;

function shader(type, src) {
  const s = gl.createShader(type);
  gl.shaderSource(s, src);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}
const program = gl.createProgram();
gl.attachShader(program, shader(gl.VERTEX_SHADER, `#version 300 es
in vec3 position; in uint patch_id; uniform mat4 mvp; uniform sampler2D radiance;
flat out vec3 colour;
void main() {
  ivec2 at = ivec2(int(patch_id) % ${TEX_W}, int(patch_id) / ${TEX_W});
  colour = texelFetch(radiance, at, 0).rgb;
  gl_Position = mvp * vec4(position, 1.0);
}`));
gl.attachShader(program, shader(gl.FRAGMENT_SHADER, `#version 300 es
precision highp float; flat in vec3 colour; uniform float scale; out vec4 out_colour;
float srgb(float x) { x = clamp(x, 0.0, 1.0); return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055; }
void main() {
  if (colour.r < 0.0) discard; // a patch absent from this frame
  vec3 c = colour * scale;
  out_colour = vec4(srgb(c.r), srgb(c.g), srgb(c.b), 1.0);
}`));
gl.linkProgram(program);
if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
const texture = gl.createTexture();
let vertexCount = 0;

async function loadMesh() {
  const bytes = await (await fetch("mesh.bin")).arrayBuffer();
  const n = new DataView(bytes).getUint32(0, true);
  const positions = new Float32Array(bytes, 4, n * 3);
  const patches = new Uint32Array(bytes.slice(4 + n * 12, 4 + n * 16));
  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  const put = (name, data, size, integer) => {
    const b = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, b);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    const at = gl.getAttribLocation(program, name);
    gl.enableVertexAttribArray(at);
    if (integer) gl.vertexAttribIPointer(at, size, gl.UNSIGNED_INT, 0, 0);
    else gl.vertexAttribPointer(at, size, gl.FLOAT, false, 0, 0);
  };
  put("position", positions, 3, false);
  put("patch_id", patches, 1, true);
  vertexCount = n;
}

function uploadRadiance() {
  const rows = Math.max(1, Math.ceil(state.patches / TEX_W));
  const texels = new Float32Array(TEX_W * rows * 3);
  texels.set(state.radiance);
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB32F, TEX_W, rows, 0, gl.RGB, gl.FLOAT, texels);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
}

// ---------------------------------------------------------------- camera

const cam = { target: [0, 0, 0], distance: 1, yaw: 0, pitch: 0, fov: 40, up: [0, 1, 0] };
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => { const l = Math.hypot(...a) || 1; return a.map((x) => x / l); };

function resetCamera() {
  const c = state.scene.camera;
  const d = sub(c.position, c.look_at);
  cam.target = c.look_at.slice();
  cam.distance = Math.hypot(...d);
  cam.yaw = Math.atan2(d[0], d[2]);
  cam.pitch = Math.asin(d[1] / cam.distance);
  cam.fov = c.fov_y_deg;
  draw();
}

function eye() {
  return [
    cam.target[0] + cam.distance * Math.cos(cam.pitch) * Math.sin(cam.yaw),
    cam.target[1] + cam.distance * Math.sin(cam.pitch),
    cam.target[2] + cam.distance * Math.cos(cam.pitch) * Math.cos(cam.yaw),
  ];
}

function matrix() {
  const e = eye();
  const f = norm(sub(cam.target, e));
  const s = norm(cross(f, [0, 1, 0]));
  const u = cross(s, f);
  const aspect = canvas.width / canvas.height;
  const t = 1 / Math.tan((cam.fov * Math.PI) / 360);
  const near = cam.distance * 0.01, far = cam.distance * 100;
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const view = [s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0, -dot(s, e), -dot(u, e), dot(f, e), 1];
  const proj = [t / aspect, 0, 0, 0, 0, t, 0, 0, 0, 0, (far + near) / (near - far), -1, 0, 0, (2 * far * near) / (near - far), 0];
  const m = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) for (let k = 0; k < 4; k++) m[c * 4 + r] += proj[k * 4 + r] * view[c * 4 + k];
  return m;
}

let dragging = null;
canvas.addEventListener("mousedown", (e) => { dragging = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 }; });
window.addEventListener("mouseup", () => { dragging = null; });
canvas.addEventListener("contextmenu", (e) => e.preventDefault());
window.addEventListener("mousemove", (e) => {
  if (!dragging) return;
  const dx = e.clientX - dragging.x, dy = e.clientY - dragging.y;
  dragging.x = e.clientX; dragging.y = e.clientY;
  if (dragging.pan) {
    const k = cam.distance * 0.002;
    const right = [Math.cos(cam.yaw), 0, -Math.sin(cam.yaw)];
    cam.target = cam.target.map((x, i) => x - right[i] * dx * k + (i === 1 ? dy * k : 0));
  } else {
    cam.yaw -= dx * 0.005;
    cam.pitch = Math.max(-1.5, Math.min(1.5, cam.pitch + dy * 0.005));
  }
  draw();
});
canvas.addEventListener("wheel", (e) => { e.preventDefault(); cam.distance *= Math.exp(e.deltaY * 0.001); draw(); }, { passive: false });

function draw() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.clearColor(0.1, 0.1, 0.1, 1);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  if (!state.radiance || !vertexCount) return;
  gl.enable(gl.DEPTH_TEST);
  gl.enable(gl.CULL_FACE); // surfaces are one-sided: their back faces render black in `render` too
  gl.useProgram(program);
  gl.uniformMatrix4fv(gl.getUniformLocation(program, "mvp"), false, matrix());
  gl.uniform1f(gl.getUniformLocation(program, "scale"), Math.pow(2, state.exposure));
  gl.activeTexture(gl.TEXTURE0);
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.uniform1i(gl.getUniformLocation(program, "radiance"), 0);
  gl.drawArrays(gl.TRIANGLES, 0, vertexCount);
  state.drawn += 1;
}
window.addEventListener("resize", draw);

// ---------------------------------------------------------------- controls

let socket;
// Latency: from a change sent to its light drawn (window.illumnet.latencies, ms).
state.latencies = [];
const send = (request) => {
  if (request.op !== "save" && !state.sentAt) state.sentAt = performance.now();
  socket.send(JSON.stringify(request));
};

function slider(parent, label, min, max, step, value, onInput) {
  const row = document.createElement("div");
  row.className = "row";
  const l = document.createElement("label");
  l.textContent = label;
  l.title = label;
  const input = document.createElement("input");
  Object.assign(input, { type: "range", min, max, step, value });
  const shown = document.createElement("span");
  shown.textContent = Number(value).toFixed(2);
  input.addEventListener("input", () => { shown.textContent = Number(input.value).toFixed(2); onInput(Number(input.value)); });
  row.append(l, input, shown);
  parent.append(row);
  return input;
}

function colour(parent, label, rgb, onInput) {
  const row = document.createElement("div");
  row.className = "row";
  const l = document.createElement("label");
  l.textContent = label;
  const input = document.createElement("input");
  input.type = "color";
  const max = Math.max(...rgb, 1e-9);
  input.value = "#" + rgb.map((x) => Math.round((255 * x) / max).toString(16).padStart(2, "0")).join("");
  input.addEventListener("input", () => {
    const v = [1, 3, 5].map((i) => parseInt(input.value.slice(i, i + 2), 16) / 255);
    onInput(v);
  });
  row.append(l, input);
  parent.append(row);
}

function buildControls() {
  const scene = state.scene;
  const emitters = $("emitters"), surfaces = $("surfaces");
  emitters.textContent = surfaces.textContent = "";
  for (const s of scene.surfaces) {
    if (Math.max(...s.emission) > 0) {
      // Intensity scales the archive's emission; colour keeps the intensity.
      const e = { scale: 1, tint: s.emission.map((x) => x / Math.max(...s.emission)), peak: Math.max(...s.emission) };
      const push = () => send({ op: "set", target: `${s.name}.emission`, value: e.tint.map((x) => x * e.peak * e.scale) });
      slider(emitters, `${s.name} ×`, 0, 4, "any", 1, (x) => { e.scale = x; push(); }).dataset.surface = s.name;
      colour(emitters, `${s.name} colour`, s.emission, (v) => { e.tint = v; push(); });
    }
    for (let c = 0; c < 3; c++) {
      const name = `${s.name} ${"RGB"[c]}`;
      const input = slider(surfaces, name, 0, 1, "any", s.reflectance[c], () => {
        const value = [0, 1, 2].map((k) => Number(surfaces.querySelector(`[data-albedo="${s.name}/${k}"]`).value));
        send({ op: "set", target: `${s.name}.reflectance`, value });
      });
      input.dataset.albedo = `${s.name}/${c}`;
    }
    if (Math.max(...s.specular) > 0) {
      // A glossy surface's k_s: what `--set NAME.specular` changes.
      for (let c = 0; c < 3; c++) {
        const input = slider(surfaces, `${s.name} kₛ ${"RGB"[c]}`, 0, 1, "any", s.specular[c], () => {
          const value = [0, 1, 2].map((k) => Number(surfaces.querySelector(`[data-specular="${s.name}/${k}"]`).value));
          send({ op: "set", target: `${s.name}.specular`, value });
        });
        input.dataset.specular = `${s.name}/${c}`;
      }
    }
  }
  const frame = $("frame");
  frame.max = scene.frames - 1;
  $("frame-row").style.display = scene.frames > 1 ? "" : "none";
  frame.oninput = () => { $("frame-value").textContent = frame.value; send({ op: "frame", frame: Number(frame.value) }); };
}

$("exposure").addEventListener("input", (e) => {
  state.exposure = Number(e.target.value);
  $("exposure-value").textContent = state.exposure.toFixed(1);
  draw();
});
$("reset-view").onclick = () => resetCamera();
$("reset").onclick = () => { send({ op: "reset" }); buildControls(); };
$("save").onclick = () => send({ op: "save" });
// The render command's image of this view, with the light shown.
$("render").onclick = () => {
  const c = state.scene.camera;
  $("rendered").textContent = "rendering…";
  socket.send(JSON.stringify({ op: "render", camera: {
    position: eye(), look_at: cam.target, up: [0, 1, 0], fov_y_deg: cam.fov, width: c.width, height: c.height } }));
};

// ---------------------------------------------------------------- server

function connect() {
  socket = new WebSocket(`ws://${location.host}/ws`);
  socket.binaryType = "arraybuffer";
  socket.onmessage = async (m) => {
    if (typeof m.data !== "string") {
      const d = new DataView(m.data);
      const n = d.getUint32(12, true);
      state.frame = d.getUint32(8, true);
      state.patches = n;
      state.radiance = new Float32Array(m.data.slice(16, 16 + n * 12));
      uploadRadiance();
      draw();
      if (state.sentAt) {
        state.latencies.push(performance.now() - state.sentAt);
        state.sentAt = 0;
      }
      return;
    }
    const msg = JSON.parse(m.data);
    if (msg.type === "scene") {
      state.scene = msg;
      await loadMesh();
      buildControls();
      resetCamera();
    } else if (msg.type === "solved") {
      state.status = msg;
      $("error").textContent = "";
      $("status").textContent =
        `frame ${msg.frame}: ${msg.iterations} iterations in ${msg.solve_ms.toFixed(1)} ms${msg.converged ? "" : " (not converged)"}\n` +
        `emitted ${msg.emitted.toPrecision(5)} W = absorbed ${msg.absorbed.toPrecision(5)} + escaped ${msg.escaped.toPrecision(5)} + residual ${msg.residual.toPrecision(3)}\n` +
        (msg.sets.length ? msg.sets.map((s) => `--set ${s}`).join("\n") : "the archive's own light");
    } else if (msg.type === "saved") {
      const a = document.createElement("a");
      a.href = URL.createObjectURL(new Blob([msg.toml], { type: "text/plain" }));
      a.download = "light.toml";
      a.click();
    } else if (msg.type === "rendered") {
      state.rendered = msg;
      const out = $("rendered");
      out.textContent = "";
      const link = document.createElement("a");
      link.href = msg.url;
      link.target = "_blank";
      const img = document.createElement("img");
      img.src = msg.url;
      link.append(img);
      const code = document.createElement("code");
      code.textContent = msg.command;
      out.append(link, code);
    } else if (msg.type === "error") {
      $("error").textContent = msg.message;
      state.lastError = msg.message;
    }
  };
  socket.onclose = () => { $("status").textContent = "disconnected: is `illumnet serve` running?"; };
}
connect();
