"""Bring your own rig: calibration files from other toolchains (`formats`), sanity checks on a converted
rig (`sanity`) and the calibration check of a capture against 2D keypoints (`check`). See docs/calibration.md."""
