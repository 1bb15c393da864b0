"""Captured data: file storage, capture import and its checks, samples and their views, masks, the sample life
cycle (state_machine), working-resolution images, the calibration check, synthetic rows for tests (seed)."""
