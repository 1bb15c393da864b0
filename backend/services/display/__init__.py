"""What the pages draw: overlays over the views, world points projected into them (view_geometry), a fit's
per-keypoint agreement, the detector's keypoints, and the reviewers' 3D scenes with their tickets."""
