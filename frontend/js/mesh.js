// The fit's mesh in the browser: decode, project into a view, and find the occluding-contour edges (an
// edge whose two faces turn opposite ways in the view) to draw the model's outline.
import { projectPoint } from "./geometry.js";

function b64ToBytes(b64) {
  const bin = atob(b64);
  const bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  return bytes;
}

export function decodeMesh(mesh) {
  const vertices = new Float32Array(b64ToBytes(mesh.vertices_f32).buffer);
  const faces = new Int32Array(b64ToBytes(mesh.faces_i32).buffer);
  if (vertices.length !== mesh.num_vertices * 3 || faces.length !== mesh.num_faces * 3) {
    throw new Error("mesh arrays do not match their declared sizes");
  }
  return { vertices, faces, ...meshEdges(faces) };
}

// Unique edges (pairs of vertex ids) and the one or two faces on each.
export function meshEdges(faces) {
  const index = new Map();
  const edges = [], edgeFaces = [];
  for (let f = 0; f < faces.length / 3; f++) {
    for (let e = 0; e < 3; e++) {
      const a = faces[3 * f + e], b = faces[3 * f + ((e + 1) % 3)];
      const key = a < b ? a * 1048576 + b : b * 1048576 + a;
      const found = index.get(key);
      if (found === undefined) {
        index.set(key, edges.length / 2);
        edges.push(Math.min(a, b), Math.max(a, b));
        edgeFaces.push(f, -1);
      } else {
        edgeFaces[2 * found + 1] = f;
      }
    }
  }
  return { edges: Uint32Array.from(edges), edgeFaces: Int32Array.from(edgeFaces) };
}

// (V, 3) metres -> Float64Array (2V) pixels, NaN behind the camera.
export function projectVertices(vertices, cam) {
  const out = new Float64Array((vertices.length / 3) * 2);
  for (let v = 0; v < vertices.length / 3; v++) {
    const p = projectPoint([vertices[3 * v], vertices[3 * v + 1], vertices[3 * v + 2]], cam);
    out[2 * v] = p ? p[0] : NaN;
    out[2 * v + 1] = p ? p[1] : NaN;
  }
  return out;
}

function signedArea(px, faces, f) {
  const a = faces[3 * f], b = faces[3 * f + 1], c = faces[3 * f + 2];
  return (px[2 * b] - px[2 * a]) * (px[2 * c + 1] - px[2 * a + 1]) - (px[2 * c] - px[2 * a]) * (px[2 * b + 1] - px[2 * a + 1]);
}

// Edge indices on the occluding contour in this view (orientation-agnostic: only the sign change counts).
export function contourEdges(projected, mesh) {
  const { faces, edgeFaces } = mesh;
  const nFaces = faces.length / 3;
  const sign = new Int8Array(nFaces);
  for (let f = 0; f < nFaces; f++) sign[f] = Math.sign(signedArea(projected, faces, f));
  const out = [];
  for (let e = 0; e < edgeFaces.length / 2; e++) {
    const f0 = edgeFaces[2 * e], f1 = edgeFaces[2 * e + 1];
    if (f1 < 0 || sign[f0] * sign[f1] < 0) out.push(e);
  }
  return out;
}
