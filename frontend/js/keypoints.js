// Keypoint helpers for every overlay; the tables come from the Python side (keypoint_table.js, generated).
import { FINGER_COLORS, KEYPOINT_NAMES, SKELETON_EDGES, SPARSE, SPARSE_LABELS } from "./keypoint_table.js";

export { FINGER_COLORS, KEYPOINT_NAMES, SKELETON_EDGES, SPARSE, SPARSE_LABELS };

export function fingerOf(keypoint) {
  return keypoint === 0 ? 0 : Math.floor((keypoint - 1) / 4) + 1;
}

export function colorOf(keypoint) {
  return FINGER_COLORS[fingerOf(keypoint)];
}

export function labelOf(keypoint) {
  const i = SPARSE.indexOf(keypoint);
  return i >= 0 ? SPARSE_LABELS[i] : KEYPOINT_NAMES[keypoint];
}
