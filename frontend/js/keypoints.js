// Keypoints in FreiHAND order (docs/conventions.md) and the colours every overlay uses per finger.
export const KEYPOINT_NAMES = [
  "wrist",
  "thumb_mcp", "thumb_pip", "thumb_dip", "thumb_tip",
  "index_mcp", "index_pip", "index_dip", "index_tip",
  "middle_mcp", "middle_pip", "middle_dip", "middle_tip",
  "ring_mcp", "ring_pip", "ring_dip", "ring_tip",
  "pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip",
];
// The sparse click set: wrist and the five fingertips, picked with keys 1..6.
export const SPARSE = [0, 4, 8, 12, 16, 20];
export const SPARSE_LABELS = ["wrist", "thumb", "index", "middle", "ring", "pinky"];
// Same colours as backend/viewer/scene.py (FINGER_RGB): wrist, thumb .. pinky.
export const FINGER_COLORS = ["#787878", "#e63946", "#f4a261", "#2a9d8f", "#457b9d", "#9d4edd"];
export const SKELETON_EDGES = Array.from({ length: 20 }, (_, i) => {
  const k = i + 1;
  return [k % 4 === 1 ? 0 : k - 1, k];
});

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
