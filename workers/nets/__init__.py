"""Networks of the bootstrap loop: HandSegNet (hand masks) and MVNet (multi-view 3D keypoints with
confidence), their data, training, prediction, checkpoints and the sparsification analysis.

See docs/networks.md. Import the submodules directly (they import torch).
"""
