"""The reviewers' 3D view and the fit geometry the browser draws.

- `hand_mesh`: a fit's mesh from its 61 parameters, in numpy (the API process never imports torch).
- `scene`: one sample's scene (mesh, skeleton, keypoints, camera frustums with their images) as a viser
  recording (`.viser` bytes) that viser's own single-file client plays back (`?playbackPath=`).
- `recorder`: the one `viser.ViserServer` per process used to serialise those scenes.
- `client`: where viser's built client lives, served by the backend at /viewer/.

Why recordings rather than a live viser server: docs/ui.md ("The 3D view").
"""
