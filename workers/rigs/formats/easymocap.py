"""EasyMocap `intri.yml` + `extri.yml` (OpenCV FileStorage YAML; ZJU-MoCap, GigaHands).

intri.yml: `names` (list of camera names), per camera `K_<name>` (3x3, pixels), `dist_<name>` (1x5
OpenCV k1 k2 p1 p2 k3) and, in newer versions, `H_<name>` / `W_<name>` (image size, pixels).
extri.yml: `names`, per camera `R_<name>` (3x1 Rodrigues, world -> camera), `Rot_<name>` (the same as a
3x3 matrix) and `T_<name>` (3x1, world -> camera, metres). When both rotations are present they must
agree. PATH is the folder holding both files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from workers.geometry.rotation import axis_angle_to_matrix
from workers.rigs.formats.common import FormatError, RawCamera, as_matrix
from workers.rigs.formats.opencv_yaml import Storage

DEFAULT_UNIT = "m"


def read(path: Path) -> tuple[list[RawCamera], list[str]]:
    """The cameras named in intri.yml's `names`, in that order (extri.yml must name the same cameras)."""
    folder = Path(path)
    if folder.is_file():
        folder = folder.parent
    intri, extri = Storage(folder / "intri.yml"), Storage(folder / "extri.yml")
    names = intri.strings("names")
    if names is None:
        raise FormatError(f"{intri.path}: missing field 'names'")
    extri_names = extri.strings("names")
    if extri_names is not None and sorted(extri_names) != sorted(names):
        raise FormatError(f"{extri.path}: field 'names' lists {len(extri_names)} cameras {sorted(extri_names)} but "
                          f"{intri.path.name} lists {len(names)} {sorted(names)}: camera count mismatch")
    raws = []
    for name in names:
        where_i, where_e = f"{intri.path}: camera {name!r}", f"{extri.path}: camera {name!r}"
        K, dist = intri.mat(f"K_{name}"), intri.mat(f"dist_{name}")
        if K is None:
            raise FormatError(f"{where_i}: missing field 'K_{name}'")
        rvec, rot, T = extri.mat(f"R_{name}"), extri.mat(f"Rot_{name}"), extri.mat(f"T_{name}")
        if T is None or (rvec is None and rot is None):
            raise FormatError(f"{where_e}: missing field(s) 'R_{name}' or 'Rot_{name}', and 'T_{name}'")
        R = as_matrix(rot, (3, 3), where_e, f"Rot_{name}") if rot is not None else None
        if rvec is not None:
            from_rvec = axis_angle_to_matrix(as_matrix(rvec, (3,), where_e, f"R_{name}"))
            if R is not None and not np.allclose(R, from_rvec, atol=1e-6):
                raise FormatError(f"{where_e}: fields 'R_{name}' (Rodrigues) and 'Rot_{name}' (matrix) disagree")
            R = from_rvec if R is None else R
        width, height = intri.number(f"W_{name}"), intri.number(f"H_{name}")
        raws.append(RawCamera(name=name, K=as_matrix(K, (3, 3), where_i, f"K_{name}"),
                              dist=np.zeros(5) if dist is None else dist.ravel(), R=R,
                              t=as_matrix(T, (3,), where_e, f"T_{name}"),
                              width=None if width is None else int(width),
                              height=None if height is None else int(height)))
    extra = sorted({k.split("_", 1)[1] for k in intri.top_level_keys() if k.startswith("K_")} - set(names))
    notes = [f"{intri.path}: K_ entries for camera(s) {extra} not in 'names' were ignored"] if extra else []
    return raws, notes
