"""The choices of ``monoavatar synth`` (no heavy imports, so the CLI's ``--help`` stays fast)."""

from __future__ import annotations

from dataclasses import dataclass

FORMAT = "monoavatar-synth-4"
"""The ``format`` a scene's ``scene.json`` records; bumped whenever the same settings make a
different scene (2: each subject's face features painted on its own face; 3: the wide
subjects' left and right local changes nearly equal; 4: the wide subjects' proportions those
of adults — standard scenes are as in 2)."""
KINDS: tuple[str, ...] = ("turnaround", "motion", "walk", "jog", "photo")
CLOTHING: tuple[str, ...] = (
    "minimal", "tight", "tshirt-shorts", "longsleeve-trousers", "loose", "skirt",
)  # fmt: skip
BACKGROUNDS: tuple[str, ...] = ("plain", "gradient", "clutter")
VARIETIES: tuple[str, ...] = ("standard", "wide")
"""Subject distributions (:func:`monoavatar.synth.subjects.sample_subject`)."""
HAIR_STYLES: tuple[str, ...] = ("cropped", "full", "bun", "long")
"""How hair lies on the head: ``cropped`` (the scalp covered evenly), ``full`` (more volume at the
top and back), ``bun`` (a knot at the back of the head), ``long`` (down the back of the head and
the nape to the neck)."""
NOISE_LEVELS: dict[str, dict[str, float]] = {
    "none": {"sigma": 0.0, "jpeg": 0, "blur": 0.0, "keypoint_jitter": 0.0},
    "low": {"sigma": 0.01, "jpeg": 92, "blur": 0.0, "keypoint_jitter": 2.0},
    "medium": {"sigma": 0.02, "jpeg": 80, "blur": 0.8, "keypoint_jitter": 4.0},
    "high": {"sigma": 0.04, "jpeg": 60, "blur": 1.5, "keypoint_jitter": 8.0},
}


@dataclass(frozen=True)
class Capture:
    """How a scene is filmed (a profile of :data:`CAPTURES`).

    Attributes:
        roll_deg: the camera turned about its line of sight by up to this many degrees.
        off_centre: the person up to this fraction of the image width off the centre (a
            third of it vertically).
        distance_min, distance_max: metres from the camera to the person.
        turns_min, turns_max: turns of a turn-around (1: exactly one).
        speed_wobble: the turning speed varies by up to this fraction of its mean.
        exposure_drift: the exposure drifts slowly by up to this gain (0.12: ±12 %).
        shutter: motion blur over this fraction of the frame interval (0: none).
        video_crf: ``video.mp4``'s H.264 constant rate factor (higher: coarser; None: the
            encoder's default rate control).
        sun: share of the light that comes from one directional light with cast shadows,
            the rest from the scene's low-order (SH) ambient light (0: ambient alone).
    """

    roll_deg: float = 0.0
    off_centre: float = 0.0
    distance_min: float = 2.2
    distance_max: float = 3.0
    turns_min: float = 1.0
    turns_max: float = 1.0
    speed_wobble: float = 0.0
    exposure_drift: float = 0.0
    shutter: float = 0.0
    video_crf: float | None = None
    sun: float = 0.0


CAPTURES: dict[str, Capture] = {
    "studio": Capture(),
    "phone": Capture(roll_deg=4.0, off_centre=0.12, distance_min=1.9, distance_max=3.6,
                     turns_min=0.85, turns_max=1.15, speed_wobble=0.35, exposure_drift=0.12,
                     shutter=0.5, video_crf=30.0, sun=0.5),
}  # fmt: skip
"""The capture profiles. ``studio``: a level camera 2.2–3.0 m away aimed at the person, one
even turn, a fixed exposure, no motion blur. ``phone``: a hand-held phone's take, rolled and
off-centre, an uneven turn of 0.85–1.15 turns, the exposure drifting, motion blur, half the
light from a sun that casts shadows, and a coarser video (CRF 30: 36 dB against the frames on
a turn-around, 39 dB by default)."""
