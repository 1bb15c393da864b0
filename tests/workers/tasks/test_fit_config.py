"""Which loss weights a fit job uses, by its source and whether its frames have masks (workers.tasks.fits)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from backend.settings import Settings
from workers.fitting.config import DETECTOR_KP2D_WEIGHT, LossWeights, source_weights
from workers.tasks.fits import fit_config


def test_a_detectors_frames_with_masks_are_led_by_their_silhouettes_and_other_sources_keep_the_papers_weights():
    ctx = SimpleNamespace(settings=Settings())
    assert fit_config(ctx, "detector", with_masks=True).weights.kp2d == DETECTOR_KP2D_WEIGHT
    # Without masks the keypoints are the only evidence: the first-round weights.
    assert fit_config(ctx, "detector", with_masks=False).weights == LossWeights()
    assert fit_config(ctx, "annotation", with_masks=True).weights == LossWeights()
    assert fit_config(ctx, "prediction", with_masks=True).weights == LossWeights.later_rounds()


def test_an_unknown_fit_source_is_an_error_naming_the_known_ones():
    with pytest.raises(ValueError, match=r"fit source must be one of .*'detector'.*not 'clicks'"):
        source_weights("clicks")
