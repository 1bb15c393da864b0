"""Which MVNet a round trains: detector-backed where the setting is on, a -detector configuration exists and the model
files are installed; paper-only otherwise, with the reason recorded."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from workers.nets.configs import CONFIGS
from workers.tasks.training import round_nets_config


def _ctx(nets_config: str, mvnet_detector: bool) -> SimpleNamespace:
    return SimpleNamespace(settings=SimpleNamespace(nets_config=nets_config, mvnet_detector=mvnet_detector))


def test_setting_off_or_no_detector_configuration_is_paper_only():
    assert round_nets_config(_ctx("cpu-small", False)) == (CONFIGS["cpu-small"], None)
    assert round_nets_config(_ctx("tiny", True)) == (CONFIGS["tiny"], None)  # no tiny-detector: the tests' rounds


def test_detector_backed_when_installed(monkeypatch):
    import workers.detector.pipeline as pipeline

    monkeypatch.setattr(pipeline, "detector_status", lambda: None)
    config, note = round_nets_config(_ctx("cpu-small", True))
    assert config is CONFIGS["cpu-small-detector"] and note is None
    assert config.mvnet.heatmap_source == "detector"
    # The HandSegNet of both is the same network: its warm start across the switch still applies.
    assert config.handsegnet == CONFIGS["cpu-small"].handsegnet


def test_missing_model_files_fall_back_with_the_reason(monkeypatch, tmp_path):
    monkeypatch.setenv("HANDLOOP_DETECTOR_DIR", str(tmp_path))
    config, note = round_nets_config(_ctx("cpu-small", True))
    assert config is CONFIGS["cpu-small"]
    assert note is not None and "is missing" in note and "paper-only" in note


@pytest.mark.parametrize("value", ["false", "0"])
def test_the_setting_reads_from_the_environment(monkeypatch, value):
    from backend.settings import Settings

    monkeypatch.setenv("HANDLOOP_MVNET_DETECTOR", value)
    assert Settings(environment="test").mvnet_detector is False
