// Cameras in the browser: projection with OpenCV distortion, its inverse, and multi-view triangulation.
// Conventions (docs/conventions.md): X_c = R X_w + t (metres), K in pixels, dist = (k1, k2, p1, p2, k3),
// pixel (0, 0) is the centre of the top-left pixel. The same numbers as cv2.projectPoints
// (tests/frontend/test_js_logic.py compares them). Written here because there is no build step and no
// linear-algebra library to import; a 4x4 symmetric eigenproblem is all triangulation needs.

function camPoint(X, cam) {
  const R = cam.R, t = cam.t;
  return [
    R[0][0] * X[0] + R[0][1] * X[1] + R[0][2] * X[2] + t[0],
    R[1][0] * X[0] + R[1][1] * X[1] + R[1][2] * X[2] + t[1],
    R[2][0] * X[0] + R[2][1] * X[1] + R[2][2] * X[2] + t[2],
  ];
}

export function distort(x, y, dist) {
  const [k1, k2, p1, p2, k3] = dist;
  const r2 = x * x + y * y;
  const radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
  return [x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y];
}

// World point (metres) -> [u, v] pixels, or null behind the camera.
export function projectPoint(X, cam) {
  const Xc = camPoint(X, cam);
  if (!(Xc[2] > 1e-6)) return null;
  const [xd, yd] = distort(Xc[0] / Xc[2], Xc[1] / Xc[2], cam.dist);
  const K = cam.K;
  return [K[0][0] * xd + K[0][1] * yd + K[0][2], K[1][1] * yd + K[1][2]];
}

export function depthOf(X, cam) {
  return camPoint(X, cam)[2];
}

// Pixel -> ideal normalised coordinates (x/z, y/z): OpenCV's fixed-point inverse of the distortion.
export function undistortPixel(uv, cam, iterations = 20) {
  const K = cam.K;
  const [k1, k2, p1, p2, k3] = cam.dist;
  const yd = (uv[1] - K[1][2]) / K[1][1];
  const xd = (uv[0] - K[0][2] - K[0][1] * yd) / K[0][0];
  let x = xd, y = yd;
  for (let i = 0; i < iterations; i++) {
    const r2 = x * x + y * y;
    const icdist = 1 / (1 + r2 * (k1 + r2 * (k2 + r2 * k3)));
    const dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x);
    const dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y;
    x = (xd - dx) * icdist;
    y = (yd - dy) * icdist;
  }
  return [x, y];
}

// Eigen-decomposition of a symmetric matrix (cyclic Jacobi). Returns {values, vectors} (vectors as columns).
export function symmetricEigen(A, sweeps = 50) {
  const n = A.length;
  const a = A.map((row) => row.slice());
  /** @type {number[][]} */
  const v = Array.from({ length: n }, (_, i) => Array.from({ length: n }, (_, j) => (i === j ? 1 : 0)));
  for (let sweep = 0; sweep < sweeps; sweep++) {
    let off = 0;
    for (let p = 0; p < n; p++) for (let q = p + 1; q < n; q++) off += a[p][q] * a[p][q];
    if (off < 1e-30) break;
    for (let p = 0; p < n; p++) {
      for (let q = p + 1; q < n; q++) {
        if (Math.abs(a[p][q]) < 1e-300) continue;
        const theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
        const t = Math.sign(theta || 1) / (Math.abs(theta) + Math.sqrt(theta * theta + 1));
        const c = 1 / Math.sqrt(t * t + 1), s = t * c;
        for (let k = 0; k < n; k++) {
          const akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (let k = 0; k < n; k++) {
          const apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (let k = 0; k < n; k++) {
          const vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
    }
  }
  return { values: a.map((row, i) => row[i]), vectors: v };
}

function dlt(observations) {
  // Rows x P3 - P1, y P3 - P2 with P = [R | t] on ideal normalised coordinates, each row normalised.
  const M = [[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]];
  for (const { cam, xy } of observations) {
    const P = cam.R.map((row, i) => [row[0], row[1], row[2], cam.t[i]]);
    for (const [coord, r] of [[xy[0], 0], [xy[1], 1]]) {
      const row = P[2].map((p2, j) => coord * p2 - P[r][j]);
      const norm = Math.hypot(row[0], row[1], row[2]) || 1;
      for (let i = 0; i < 4; i++) for (let j = 0; j < 4; j++) M[i][j] += (row[i] * row[j]) / (norm * norm);
    }
  }
  const { values, vectors } = symmetricEigen(M);
  let best = 0;
  for (let i = 1; i < 4; i++) if (values[i] < values[best]) best = i;
  const X = vectors.map((row) => row[best]);
  if (Math.abs(X[3]) < 1e-12) return null;
  return [X[0] / X[3], X[1] / X[3], X[2] / X[3]];
}

// Triangulate one point from >= 2 views: observations [{cam, pixel: [u, v]}]. Views whose reprojection
// error exceeds outlierPx are dropped one at a time (worst first) while 3 or more remain.
// Returns {point, errors_px, used} or null.
export function triangulate(observations, outlierPx = 12) {
  let obs = observations
    .filter((o) => o.pixel && Number.isFinite(o.pixel[0]) && Number.isFinite(o.pixel[1]))
    .map((o) => ({ ...o, xy: undistortPixel(o.pixel, o.cam) }));
  while (obs.length >= 2) {
    const point = dlt(obs);
    if (point === null) return null;
    const errors = obs.map((o) => {
      const p = projectPoint(point, o.cam);
      return p === null ? Infinity : Math.hypot(p[0] - o.pixel[0], p[1] - o.pixel[1]);
    });
    let worst = 0;
    for (let i = 1; i < errors.length; i++) if (errors[i] > errors[worst]) worst = i;
    if (errors[worst] <= outlierPx || obs.length < 3) {
      if (errors.some((e) => !Number.isFinite(e))) return null;
      return { point, errors_px: errors, used: obs.map((o) => o.cam.view_id) };
    }
    obs = obs.filter((_, i) => i !== worst);
  }
  return null;
}

// The epipolar curve in camTo of pixel `uv` in camFrom: the ray through that pixel, sampled at depths
// (metres along camFrom's optical axis, geometric steps) and projected with distortion. [[u, v], ...] px,
// points behind camTo left out.
export function epipolarCurve(uv, camFrom, camTo, { nearM = 0.05, farM = 5.0, steps = 48 } = {}) {
  const [x, y] = undistortPixel(uv, camFrom);
  const { R, t } = camFrom;
  const out = [];
  for (let i = 0; i <= steps; i++) {
    const z = nearM * Math.pow(farM / nearM, i / steps);
    const c = [x * z - t[0], y * z - t[1], z - t[2]]; // X_c - t, then R^T: the world point
    const X = [0, 1, 2].map((j) => R[0][j] * c[0] + R[1][j] * c[1] + R[2][j] * c[2]);
    const p = projectPoint(X, camTo);
    if (p && Number.isFinite(p[0]) && Number.isFinite(p[1])) out.push(p);
  }
  return out;
}
