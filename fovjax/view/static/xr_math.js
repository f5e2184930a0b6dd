// fovjax view --xr: the geometry of the headset page's reprojection (no DOM, no WebGL: the page
// and tests/test_view_xr.py, through Node, run the same functions).
//
// Conventions: 3x3 matrices are row-major arrays of 9, 4x4 matrices column-major arrays of 16
// (WebXR's projection matrices), quaternions [x, y, z, w] (WebXR's order). A rendered eye is
// {rotation: local-from-eye 3x3, tangents: [left, right, bottom, top]} as the server sends it
// (`XRStereo.page_json`): its image covers those tangents of its -z axis, row 0 at the top.
"use strict";

(function (root) {
  function quatToMat3(q) {
    const [x, y, z, w] = q;
    return [
      1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
      2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
      2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ];
  }

  function mat3Transpose(a) {
    return [a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]];
  }

  function mat3Mul(a, b) {
    const out = new Array(9);
    for (let i = 0; i < 3; i++) {
      for (let j = 0; j < 3; j++) {
        out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
      }
    }
    return out;
  }

  function mat3Vec(a, v) {
    return [
      a[0] * v[0] + a[1] * v[1] + a[2] * v[2],
      a[3] * v[0] + a[4] * v[1] + a[5] * v[2],
      a[6] * v[0] + a[7] * v[1] + a[8] * v[2],
    ];
  }

  // The inverse of a column-major 4x4 matrix (cofactors), or null when it is singular.
  function mat4Invert(m) {
    const inv = new Array(16);
    inv[0] = m[5] * m[10] * m[15] - m[5] * m[11] * m[14] - m[9] * m[6] * m[15] + m[9] * m[7] * m[14] + m[13] * m[6] * m[11] - m[13] * m[7] * m[10];
    inv[4] = -m[4] * m[10] * m[15] + m[4] * m[11] * m[14] + m[8] * m[6] * m[15] - m[8] * m[7] * m[14] - m[12] * m[6] * m[11] + m[12] * m[7] * m[10];
    inv[8] = m[4] * m[9] * m[15] - m[4] * m[11] * m[13] - m[8] * m[5] * m[15] + m[8] * m[7] * m[13] + m[12] * m[5] * m[11] - m[12] * m[7] * m[9];
    inv[12] = -m[4] * m[9] * m[14] + m[4] * m[10] * m[13] + m[8] * m[5] * m[14] - m[8] * m[6] * m[13] - m[12] * m[5] * m[10] + m[12] * m[6] * m[9];
    inv[1] = -m[1] * m[10] * m[15] + m[1] * m[11] * m[14] + m[9] * m[2] * m[15] - m[9] * m[3] * m[14] - m[13] * m[2] * m[11] + m[13] * m[3] * m[10];
    inv[5] = m[0] * m[10] * m[15] - m[0] * m[11] * m[14] - m[8] * m[2] * m[15] + m[8] * m[3] * m[14] + m[12] * m[2] * m[11] - m[12] * m[3] * m[10];
    inv[9] = -m[0] * m[9] * m[15] + m[0] * m[11] * m[13] + m[8] * m[1] * m[15] - m[8] * m[3] * m[13] - m[12] * m[1] * m[11] + m[12] * m[3] * m[9];
    inv[13] = m[0] * m[9] * m[14] - m[0] * m[10] * m[13] - m[8] * m[1] * m[14] + m[8] * m[2] * m[13] + m[12] * m[1] * m[10] - m[12] * m[2] * m[9];
    inv[2] = m[1] * m[6] * m[15] - m[1] * m[7] * m[14] - m[5] * m[2] * m[15] + m[5] * m[3] * m[14] + m[13] * m[2] * m[7] - m[13] * m[3] * m[6];
    inv[6] = -m[0] * m[6] * m[15] + m[0] * m[7] * m[14] + m[4] * m[2] * m[15] - m[4] * m[3] * m[14] - m[12] * m[2] * m[7] + m[12] * m[3] * m[6];
    inv[10] = m[0] * m[5] * m[15] - m[0] * m[7] * m[13] - m[4] * m[1] * m[15] + m[4] * m[3] * m[13] + m[12] * m[1] * m[7] - m[12] * m[3] * m[5];
    inv[14] = -m[0] * m[5] * m[14] + m[0] * m[6] * m[13] + m[4] * m[1] * m[14] - m[4] * m[2] * m[13] - m[12] * m[1] * m[6] + m[12] * m[2] * m[5];
    inv[3] = -m[1] * m[6] * m[11] + m[1] * m[7] * m[10] + m[5] * m[2] * m[11] - m[5] * m[3] * m[10] - m[9] * m[2] * m[7] + m[9] * m[3] * m[6];
    inv[7] = m[0] * m[6] * m[11] - m[0] * m[7] * m[10] - m[4] * m[2] * m[11] + m[4] * m[3] * m[10] + m[8] * m[2] * m[7] - m[8] * m[3] * m[6];
    inv[11] = -m[0] * m[5] * m[11] + m[0] * m[7] * m[9] + m[4] * m[1] * m[11] - m[4] * m[3] * m[9] - m[8] * m[1] * m[7] + m[8] * m[3] * m[5];
    inv[15] = m[0] * m[5] * m[10] - m[0] * m[6] * m[9] - m[4] * m[1] * m[10] + m[4] * m[2] * m[9] + m[8] * m[1] * m[6] - m[8] * m[2] * m[5];
    const det = m[0] * inv[0] + m[1] * inv[4] + m[2] * inv[8] + m[3] * inv[12];
    if (!det) return null;
    return inv.map((v) => v / det);
  }

  // The angle (degrees) of the rotation between two unit quaternions.
  function angleDeg(qa, qb) {
    const dot = Math.abs(qa[0] * qb[0] + qa[1] * qb[1] + qa[2] * qb[2] + qa[3] * qb[3]);
    return (2 * Math.acos(Math.min(1, dot)) * 180) / Math.PI;
  }

  // The rendered eye's frame from the displayed view's (both local-from-eye): the rotation the
  // fragment shader applies to each display ray (row-major 3x3).
  function renderFromView(eyeRotation, viewQuaternion) {
    return mat3Mul(mat3Transpose(eyeRotation), quatToMat3(viewQuaternion));
  }

  // What the fragment shader does for one display pixel: `ndc` ([-1, 1]^2, y up) of the view
  // with inverse projection `invProj` -> (u, v) in the rendered eye's image ([0, 1]^2, v down),
  // or null where the display ray misses the rendered frame.
  function frameUV(renderFromViewMatrix, tangents, invProj, ndc) {
    const [x, y] = ndc;
    // A point of the near plane in the view's frame: the direction of the display ray.
    const p = [
      invProj[0] * x + invProj[4] * y - invProj[8] + invProj[12],
      invProj[1] * x + invProj[5] * y - invProj[9] + invProj[13],
      invProj[2] * x + invProj[6] * y - invProj[10] + invProj[14],
      invProj[3] * x + invProj[7] * y - invProj[11] + invProj[15],
    ];
    const d = mat3Vec(renderFromViewMatrix, [p[0] / p[3], p[1] / p[3], p[2] / p[3]]);
    if (!(d[2] < 0)) return null;
    const tx = d[0] / -d[2], ty = d[1] / -d[2];
    const [left, right, bottom, top] = tangents;
    const u = (tx - left) / (right - left), v = (top - ty) / (top - bottom);
    return u < 0 || u > 1 || v < 0 || v > 1 ? null : [u, v];
  }

  const api = { quatToMat3, mat3Transpose, mat3Mul, mat3Vec, mat4Invert, angleDeg, renderFromView, frameUV };
  if (typeof module !== "undefined" && module.exports) module.exports = api;
  else root.fovjaxXRMath = api;
})(typeof self !== "undefined" ? self : this);
