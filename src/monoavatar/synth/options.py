"""The choices of ``monoavatar synth`` (no heavy imports, so the CLI's ``--help`` stays fast)."""

from __future__ import annotations

FORMAT = "monoavatar-synth-2"
"""The ``format`` a scene's ``scene.json`` records; bumped whenever the same settings make a
different scene (2: each subject's face features painted on its own face)."""
KINDS: tuple[str, ...] = ("turnaround", "motion", "walk", "jog", "photo")
CLOTHING: tuple[str, ...] = (
    "minimal", "tight", "tshirt-shorts", "longsleeve-trousers", "loose", "skirt",
)  # fmt: skip
BACKGROUNDS: tuple[str, ...] = ("plain", "gradient", "clutter")
NOISE_LEVELS: dict[str, dict[str, float]] = {
    "none": {"sigma": 0.0, "jpeg": 0, "blur": 0.0, "keypoint_jitter": 0.0},
    "low": {"sigma": 0.01, "jpeg": 92, "blur": 0.0, "keypoint_jitter": 2.0},
    "medium": {"sigma": 0.02, "jpeg": 80, "blur": 0.8, "keypoint_jitter": 4.0},
    "high": {"sigma": 0.04, "jpeg": 60, "blur": 1.5, "keypoint_jitter": 8.0},
}
