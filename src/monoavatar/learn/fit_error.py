"""How our single-image fitter errs on synthetic photos: the residual pose, translation and
phenotypes of :func:`monoavatar.fit.pose.fit_photo` after mediapipe perception, summarised
as the Gaussian :class:`~monoavatar.learn.photo_data.FitError` that training samples from."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from monoavatar.body import BodyModel, lbs
from monoavatar.fit.pose import PoseFitError, PoseSettings, fit_photo
from monoavatar.learn.photo_data import PHENOTYPES, FitError, PhotoDataSettings, render_photo

__all__ = ["FitResiduals", "measure_fit_error"]


@dataclass
class FitResiduals:
    """Per photo: rotation residuals (P, J, 3) radians (axis-angle of ``R_true^T R_fit``),
    translation residuals (P, 3) metres in camera axes (the fit scaled to the true height),
    phenotype residuals (P, 6), and the seeds of photos where no person was found."""

    rotation: np.ndarray
    translation: np.ndarray
    shape: np.ndarray
    skipped: list[int]


def _height(body: BodyModel, shape: torch.Tensor) -> float:
    with torch.no_grad():
        rest, _ = body.rest_shape(shape)
    return float(rest[0, :, 1].max() - rest[0, :, 1].min())


def residuals(fit_body: BodyModel, seeds: list[int], local_body: BodyModel,
              settings: PhotoDataSettings, progress: bool = True) -> FitResiduals:  # fmt: skip
    """Fit every photo of ``seeds`` (mediapipe perception, :func:`fit_photo`) and compare."""
    from monoavatar.perception import default_detectors, perceive_image
    from monoavatar.perception.mediapipe_backend import native_stderr_hidden

    rot, trans, shape, skipped = [], [], [], []
    # the graphs' threads log as they start, after a photo's own hidden block has ended
    with native_stderr_hidden(), default_detectors() as detectors:
        for seed in tqdm(seeds, desc="fitter error", unit="photo", disable=not progress):
            scene = render_photo(local_body, seed, settings)
            obs = perceive_image(scene.image, scene.camera, detectors=detectors)
            try:
                track = fit_photo(fit_body, obs, PoseSettings())
            except PoseFitError:
                skipped.append(seed)
                continue
            r_true = lbs.axis_angle_to_matrix(torch.as_tensor(scene.pose, dtype=torch.float64))
            r_fit = lbs.axis_angle_to_matrix(torch.as_tensor(track.poses[0],
                                                             dtype=torch.float64))  # fmt: skip
            rot.append(lbs.matrix_to_axis_angle(r_true.transpose(-1, -2) @ r_fit).numpy())
            # the root joint's world position, in camera axes
            with torch.no_grad():
                s = torch.as_tensor(track.shape, dtype=fit_body.dtype)[None]
                _, j_fit = fit_body.rest_shape(s)
                s_true = torch.as_tensor(scene.subject.spec.shape[:PHENOTYPES],
                                         dtype=fit_body.dtype)[None]  # fmt: skip
                _, j_true = fit_body.rest_shape(s_true)
            # the root joint in camera axes, the fit scaled to the true height (an up-to-scale
            # fit's size and depth are one unknown; the image fixes only their ratio)
            ratio = _height(fit_body, s_true) / _height(fit_body, s)
            cam = scene.camera
            root_fit = cam.R @ (j_fit[0, 0].double().numpy() + track.translations[0]) + cam.t
            root_true = cam.R @ (j_true[0, 0].double().numpy() + scene.translation) + cam.t
            trans.append(root_fit * ratio - root_true)
            shape.append(track.shape[:PHENOTYPES] - scene.subject.spec.shape[:PHENOTYPES])
    if not rot:
        raise PoseFitError("the fitter found no person in any of the synthetic photos")
    return FitResiduals(np.stack(rot), np.stack(trans), np.stack(shape), skipped)


def measure_fit_error(fit_body: BodyModel, local_body: BodyModel, seeds: list[int],
                      settings: PhotoDataSettings, progress: bool = True) -> FitError:
    """The fitter's error on the photos of ``seeds`` as independent Gaussians: the root mean
    square of each residual component (a zero-mean fit)."""
    r = residuals(fit_body, seeds, local_body, settings, progress)
    rms = lambda a: np.sqrt(np.mean(a**2, axis=0))  # noqa: E731
    return FitError(rms(r.rotation), rms(r.translation), rms(r.shape), len(r.rotation))
