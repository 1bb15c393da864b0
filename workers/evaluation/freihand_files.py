"""Reading FreiHAND's evaluation inputs with clear errors: a prediction file `pred.json` holding
`[xyz_list, verts_list]` and the ground truth `<set>_xyz.json` / `<set>_verts.json` of a dataset folder
(FreiHAND's own or one written by `handloop export --format freihand`). Metres throughout."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

NUM_KEYPOINTS = 21
SET_NAMES = ("training", "evaluation")


class EvaluationInputError(ValueError):
    """An evaluation input file is missing or malformed; the message names the file and what is wrong."""


@dataclass(frozen=True, eq=False)
class PointSets:
    """Keypoints and meshes of S samples.

    Attributes:
        xyz: (S, 21, 3) float64 keypoints, metres.
        verts: (S, V, 3) float64 vertices, metres.
        source: where they were read from (for messages).
    """

    xyz: np.ndarray
    verts: np.ndarray
    source: str

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


def load_json(path: Path) -> Any:
    """Parse a JSON file; EvaluationInputError naming the file when it is absent or not JSON.
    NaN and Infinity literals are refused (they are not JSON)."""

    def refuse_constant(name: str) -> float:
        raise EvaluationInputError(f"{path}: contains {name}, which is not a finite number")

    try:
        with open(path, encoding="utf-8") as handle:
            return json.load(handle, parse_constant=refuse_constant)
    except FileNotFoundError:
        raise EvaluationInputError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise EvaluationInputError(f"{path}: is a folder, not a JSON file") from None
    except UnicodeDecodeError as exc:
        raise EvaluationInputError(f"{path}: not a UTF-8 text file ({exc.reason})") from None
    except json.JSONDecodeError as exc:
        raise EvaluationInputError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") \
            from None


def _point_array(entries: Any, where: str, rows: int | None) -> np.ndarray:
    """(S, rows, 3) float64 from a list of S lists of [x, y, z]; `rows` None = any count, the same for all."""
    if not isinstance(entries, list):
        raise EvaluationInputError(f"{where}: expected a list of samples, got {type(entries).__name__}")
    if not entries:
        raise EvaluationInputError(f"{where}: no samples")
    out = []
    expected = rows
    for i, entry in enumerate(entries):
        try:
            array = np.asarray(entry, dtype=np.float64)
        except (TypeError, ValueError):
            raise EvaluationInputError(f"{where}: sample {i} is not a list of [x, y, z] numbers") from None
        if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] == 0:
            raise EvaluationInputError(f"{where}: sample {i} must have shape (N, 3), got {array.shape}")
        if expected is None:
            expected = array.shape[0]
        if array.shape[0] != expected:
            what = "keypoints" if rows is not None else "vertices (every sample must have as many as sample 0)"
            raise EvaluationInputError(f"{where}: sample {i} has {array.shape[0]} points; expected {expected} "
                                       f"{what}")
        if not np.isfinite(array).all():
            raise EvaluationInputError(f"{where}: sample {i} contains non-finite numbers")
        out.append(array)
    return np.stack(out)


def load_predictions(path: Path | str) -> PointSets:
    """Read a FreiHAND prediction file: `[xyz_list, verts_list]` (a folder means its pred.json)."""
    path = Path(path)
    if path.is_dir():
        path = path / "pred.json"
    data = load_json(path)
    if not isinstance(data, list) or len(data) != 2:
        got = f"a list of length {len(data)}" if isinstance(data, list) else type(data).__name__
        raise EvaluationInputError(f"{path}: expected [xyz_list, verts_list] (a list of two lists), got {got}")
    xyz = _point_array(data[0], f"{path} (xyz_list)", NUM_KEYPOINTS)
    verts = _point_array(data[1], f"{path} (verts_list)", None)
    if len(xyz) != len(verts):
        raise EvaluationInputError(f"{path}: {len(xyz)} keypoint sets but {len(verts)} meshes")
    return PointSets(xyz=xyz, verts=verts, source=str(path))


def load_ground_truth(folder: Path | str, set_name: str = "evaluation") -> PointSets:
    """Read `<set>_xyz.json` and `<set>_verts.json` from a FreiHAND-layout folder."""
    if set_name not in SET_NAMES:
        raise EvaluationInputError(f"set must be one of {SET_NAMES}, not {set_name!r}")
    folder = Path(folder)
    if not folder.is_dir():
        raise EvaluationInputError(f"{folder}: not a folder (expected a dataset folder holding {set_name}_xyz.json "
                                   f"and {set_name}_verts.json)")
    xyz_path, verts_path = folder / f"{set_name}_xyz.json", folder / f"{set_name}_verts.json"
    xyz = _point_array(load_json(xyz_path), str(xyz_path), NUM_KEYPOINTS)
    verts = _point_array(load_json(verts_path), str(verts_path), None)
    if len(xyz) != len(verts):
        raise EvaluationInputError(f"{folder}: {xyz_path.name} has {len(xyz)} samples but {verts_path.name} has "
                                   f"{len(verts)}")
    return PointSets(xyz=xyz, verts=verts, source=str(folder))


def check_pair(pred: PointSets, gt: PointSets) -> None:
    """The prediction must have one entry per ground-truth sample (the official script asserts the same)."""
    if len(pred) != len(gt):
        raise EvaluationInputError(f"{pred.source} has {len(pred)} samples but the ground truth {gt.source} has "
                                   f"{len(gt)}: one prediction per ground-truth sample, in the same order")

