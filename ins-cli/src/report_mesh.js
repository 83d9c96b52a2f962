// The report's 3D view of the exported mesh: a binary glTF (`mesh.js` sets
// window.INS_MESH_GLB to its base64, since browsers refuse to fetch files or load modules from
// a page opened as file://) drawn with WebGL, vertex colours unlit, orbiting under the mouse.
// Written here, not vendored: three.js is module-only since r160, and modules do not load from
// file:// either. Sets data-mesh on the canvas: "ok <vertices>" once drawn, or the reason.
(function () {
  "use strict";
  const canvas = document.getElementById("mesh");
  const fail = (why) => { canvas.dataset.mesh = "error: " + why; canvas.insertAdjacentText("afterend", " (3D view unavailable: " + why + ")"); };
  if (!window.INS_MESH_GLB) return fail("no mesh data");
  const bin = Uint8Array.from(atob(window.INS_MESH_GLB), (c) => c.charCodeAt(0));
  const dv = new DataView(bin.buffer);
  if (dv.getUint32(0, true) !== 0x46546c67) return fail("not a binary glTF");
  const jsonLen = dv.getUint32(12, true);
  const gltf = JSON.parse(new TextDecoder().decode(bin.subarray(20, 20 + jsonLen)));
  const binStart = 20 + jsonLen + 8;
  const prim = gltf.meshes[0].primitives[0];
  const view = (index, Type, width) => {
    const a = gltf.accessors[index], v = gltf.bufferViews[a.bufferView];
    return { data: new Type(bin.buffer, binStart + (v.byteOffset || 0) + (a.byteOffset || 0), a.count * width), accessor: a };
  };
  const pos = view(prim.attributes.POSITION, Float32Array, 3);
  const col = view(prim.attributes.COLOR_0, Uint16Array, 4);
  const idx = view(prim.indices, Uint32Array, 1);
  const gl = canvas.getContext("webgl2") || canvas.getContext("webgl");
  if (!gl) return fail("this browser has no WebGL");
  if (!(gl instanceof WebGL2RenderingContext) && !gl.getExtension("OES_element_index_uint")) return fail("no 32-bit indices");
  const shader = (type, src) => { const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s); return s; };
  const prog = gl.createProgram();
  gl.attachShader(prog, shader(gl.VERTEX_SHADER,
    "attribute vec3 p; attribute vec4 c; uniform mat4 m; varying vec3 v;" +
    "void main(){ gl_Position = m * vec4(p, 1.0); v = c.rgb; }"));
  gl.attachShader(prog, shader(gl.FRAGMENT_SHADER,
    "precision mediump float; varying vec3 v;" +
    "void main(){ gl_FragColor = vec4(pow(v, vec3(1.0 / 2.2)), 1.0); }"));
  gl.linkProgram(prog);
  if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) return fail("shaders: " + gl.getProgramInfoLog(prog));
  gl.useProgram(prog);
  const buffer = (target, data) => { const b = gl.createBuffer(); gl.bindBuffer(target, b); gl.bufferData(target, data, gl.STATIC_DRAW); return b; };
  buffer(gl.ARRAY_BUFFER, pos.data);
  const lp = gl.getAttribLocation(prog, "p");
  gl.enableVertexAttribArray(lp); gl.vertexAttribPointer(lp, 3, gl.FLOAT, false, 0, 0);
  buffer(gl.ARRAY_BUFFER, col.data);
  const lc = gl.getAttribLocation(prog, "c");
  gl.enableVertexAttribArray(lc); gl.vertexAttribPointer(lc, 4, gl.UNSIGNED_SHORT, true, 0, 0);
  buffer(gl.ELEMENT_ARRAY_BUFFER, idx.data);
  // The node's rotation (the scene's up to +Y), then the box centred at the origin.
  const [qx, qy, qz, qw] = (gltf.nodes[0].rotation || [0, 0, 0, 1]);
  const R = [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy + qz * qw), 2 * (qx * qz - qy * qw),
             2 * (qx * qy - qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz + qx * qw),
             2 * (qx * qz + qy * qw), 2 * (qy * qz - qx * qw), 1 - 2 * (qx * qx + qy * qy)]; // columns
  const lo = pos.accessor.min, hi = pos.accessor.max;
  const centre = [0, 1, 2].map((k) => (lo[k] + hi[k]) / 2);
  const radius = Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2 || 1;
  const mul = (a, b) => { const o = new Array(16).fill(0); for (let i = 0; i < 4; i++) for (let j = 0; j < 4; j++) for (let k = 0; k < 4; k++) o[j * 4 + i] += a[k * 4 + i] * b[j * 4 + k]; return o; };
  let az = 0.6, el = 0.35;
  const draw = () => {
    const model = [R[0], R[1], R[2], 0, R[3], R[4], R[5], 0, R[6], R[7], R[8], 0, 0, 0, 0, 1];
    const shift = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, -centre[0], -centre[1], -centre[2], 1];
    const ca = Math.cos(az), sa = Math.sin(az), ce = Math.cos(el), se = Math.sin(el);
    const yaw = [ca, 0, -sa, 0, 0, 1, 0, 0, sa, 0, ca, 0, 0, 0, 0, 1];
    const pitch = [1, 0, 0, 0, 0, ce, se, 0, 0, -se, ce, 0, 0, 0, 0, 1];
    const d = 2.4 * radius, n = 0.05 * radius, f = 10 * radius, t = 1 / Math.tan(Math.PI / 10);
    const back = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, -d, 1];
    const proj = [t, 0, 0, 0, 0, t, 0, 0, 0, 0, (f + n) / (n - f), -1, 0, 0, 2 * f * n / (n - f), 0];
    const m = mul(proj, mul(back, mul(pitch, mul(yaw, mul(model, shift)))));
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(1, 1, 1, 1);
    gl.enable(gl.DEPTH_TEST);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.uniformMatrix4fv(gl.getUniformLocation(prog, "m"), false, new Float32Array(m));
    gl.drawElements(gl.TRIANGLES, idx.accessor.count, gl.UNSIGNED_INT, 0);
  };
  let drag = null;
  canvas.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    az += (e.clientX - drag[0]) * 0.01;
    el = Math.max(-1.5, Math.min(1.5, el + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY];
    draw();
  });
  canvas.addEventListener("pointerup", () => { drag = null; });
  draw();
  canvas.dataset.mesh = gl.getError() === gl.NO_ERROR ? "ok " + pos.accessor.count : "error: WebGL error " + gl.getError();
})();
