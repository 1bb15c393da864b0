"""Synthetic subjects: hand shape (betas) and skin tone, and the per-vertex skin albedo they imply.

Skin tones are the ten Monk Skin Tone swatches (HAND_ANATOMY.md): rendering variety across the range,
not measurements of hand skin.
"""

from __future__ import annotations

import numpy as np

from workers.capture.schema import Subject
from workers.handmodel.keypoints import NUM_BETAS
from workers.synth.compositing import hex_to_srgb, srgb_to_linear

MONK_SKIN_TONES: tuple[str, ...] = ("#f6ede4", "#f3e7db", "#f7ead0", "#eadaba", "#d7bd96",
                                    "#a07e56", "#825c43", "#604134", "#3a312a", "#292420")
BETA_LIMIT_SD = 2.0


def sample_subjects(count: int, rng: np.random.Generator) -> list[Subject]:
    """`count` subjects "subj00", "subj01", ...: betas ~ N(0, 0.8) clipped to +-2 SD; skin tones
    spread over the Monk scale (a random permutation, then cycled)."""
    tones = rng.permutation(len(MONK_SKIN_TONES))
    subjects = []
    for i in range(count):
        betas = np.clip(rng.normal(0.0, 0.8, NUM_BETAS), -BETA_LIMIT_SD, BETA_LIMIT_SD)
        subjects.append(Subject(id=f"subj{i:02d}", betas=np.round(betas, 4), skin_tone=MONK_SKIN_TONES[
            tones[i % len(tones)]], sex=None, notes="synthetic"))
    return subjects


def skin_albedo(skin_tone: str, vertices: np.ndarray, rng: np.random.Generator,
                variation: float = 0.06) -> np.ndarray:
    """Per-vertex linear albedo: the tone with slight smooth blotchiness and redder knuckles/tips.

    Args:
        skin_tone: sRGB hex colour.
        vertices: (V, 3) rest-pose vertices, metres (positions drive the smooth variation).
        rng: seeds the variation.
        variation: relative amplitude of the brightness variation.
    Returns:
        (V, 3) float32 linear RGB in [0, 1].
    """
    base = srgb_to_linear(hex_to_srgb(skin_tone))
    v = np.asarray(vertices, dtype=np.float64)
    freq = rng.normal(0.0, 60.0, (4, 3))  # waves of ~2-10 cm
    phase = rng.uniform(0, 2 * np.pi, 4)
    smooth = np.sin(v @ freq.T + phase).mean(axis=1)  # (V,) in [-1, 1]
    speckle = rng.normal(0.0, 0.3, len(v))
    brightness = 1.0 + variation * (smooth + 0.3 * speckle)
    redness = np.clip(smooth, 0, 1) * 0.04
    albedo = base[None] * brightness[:, None]
    albedo[:, 0] *= 1.0 + redness
    albedo[:, 2] *= 1.0 - redness
    return np.clip(albedo, 0, 1).astype(np.float32)
