"""Camera intrinsics for an input: from the user, or a documented default.

Default focal length
--------------------
Without calibration we assume a phone's main camera filming video. Phone main cameras are
24-28 mm equivalent (≈75-84° diagonal field of view on the full 4:3 photo). Video crops the
sensor to 16:9 (≈8 % less diagonal) and electronic stabilisation takes another ≈10 % margin, so
recorded video sees ≈65-70° across its diagonal. We take ``DEFAULT_DIAGONAL_FOV_DEG = 68`` and
express the focal length in terms of the image diagonal ``d = hypot(W, H)`` in pixels::

    f = d / (2 tan(34°)) ≈ 0.741 d

which is independent of portrait/landscape orientation and scales with resizing. For a
1080×1920 portrait video this gives f ≈ 1633 px (0.85 H); Paper D instead fixes f to the image
height (f = H = 1920 px, ≈60° diagonal): the two differ by ≈15 %.

How much it matters: for a person standing 2-4 m away the camera is close to weak perspective
(the body's depth extent, ≈0.3 m, is < 15 % of the distance). A focal error of x % is then
absorbed almost entirely by the estimated distance (``z ≈ f · height_m / height_px`` changes by
x %); body shape changes only through the residual perspective foreshortening, a second-order
effect of ≈ x % × (depth extent / distance), i.e. ≈1-2 % of body size, a few millimetres to a
centimetre for a 15 % focal error. Close-ups (< 1 m) and wide-angle lenses are more sensitive:
give ``focal_px`` or a ``camera.json`` then. A video that was *cropped* (e.g. a square crop of a
16:9 video, as in People-Snapshot) keeps the focal length of the uncropped frame, which the
diagonal rule underestimates; give the focal for such inputs.
"""

from __future__ import annotations

import math
from pathlib import Path

from monoavatar.core.camera import CameraError, PinholeCamera

DEFAULT_DIAGONAL_FOV_DEG = 68.0
"""Assumed diagonal field of view of an uncalibrated video, degrees (see the module docstring)."""


def default_focal(width: int, height: int, diagonal_fov_deg: float = DEFAULT_DIAGONAL_FOV_DEG
                  ) -> float:
    """Focal length in pixels for an image of ``width`` × ``height`` pixels whose diagonal spans
    ``diagonal_fov_deg`` degrees: ``hypot(W, H) / (2 tan(fov / 2))``."""
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if not 0.0 < diagonal_fov_deg < 180.0:
        raise ValueError(f"diagonal_fov_deg must be in (0, 180), got {diagonal_fov_deg}")
    return math.hypot(width, height) / (2.0 * math.tan(math.radians(diagonal_fov_deg) / 2.0))


def default_camera(width: int, height: int) -> PinholeCamera:
    """The default camera: :func:`default_focal`, square pixels, principal point at the image
    centre ``(W/2, H/2)`` (pixel origin at the top-left corner), identity extrinsics."""
    return PinholeCamera.from_focal(default_focal(width, height), width, height)


def resolve_camera(
    width: int,
    height: int,
    *,
    focal_px: float | None = None,
    camera_path: str | Path | None = None,
) -> PinholeCamera:
    """The camera for frames of ``width`` × ``height`` pixels (display orientation).

    Args:
        focal_px: focal length in pixels (square pixels, principal point at the centre).
        camera_path: a ``camera.json`` written by :meth:`PinholeCamera.save_json`. A camera
            for another resolution of the same aspect ratio is rescaled; another aspect ratio
            is an error.
    Neither given: :func:`default_camera`.
    Raises:
        CameraError: both given, a non-positive focal, or a camera file for another image.
    """
    if focal_px is not None and camera_path is not None:
        raise CameraError("give either focal_px or camera_path, not both")
    if focal_px is not None:
        if not (math.isfinite(focal_px) and focal_px > 0):
            raise CameraError(f"focal_px must be a positive number of pixels, got {focal_px}")
        return PinholeCamera.from_focal(float(focal_px), width, height)
    if camera_path is not None:
        camera = PinholeCamera.load_json(camera_path)
        if (camera.width, camera.height) == (width, height):
            return camera
        factor = width / camera.width
        if abs(camera.height * factor - height) <= 1.0:
            return camera.scaled(factor)
        hint = (
            " (it looks like the size before the video's rotation was applied; frames are in "
            "display orientation)"
            if (camera.width, camera.height) == (height, width)
            else ""
        )
        raise CameraError(
            f"{camera_path}: camera is for {camera.width}x{camera.height} images, the frames are "
            f"{width}x{height}{hint}"
        )
    return default_camera(width, height)
