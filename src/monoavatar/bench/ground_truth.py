"""The surface error of one reconstruction against its synth folder's ground truth, with the
benchmark's protocol; ``demo``, ``reconstruct`` and ``fit-shape`` print it for synth inputs."""

from __future__ import annotations

import numpy as np
import torch

from monoavatar.bench.metrics import Rig, surface_metrics
from monoavatar.body import BodyModel
from monoavatar.datasets.synth_scene import SynthGroundTruth
from monoavatar.fit.shape import CanonicalShape
from monoavatar.io.avatar_folder import GroundTruthSummary


def ground_truth_error(body: BodyModel, shape: CanonicalShape,
                       truth: SynthGroundTruth) -> GroundTruthSummary:  # fmt: skip
    """The canonical avatar's surface error against the truth's first subject, in mm: after a
    similarity transform and the avatar's articulated pose fitted to the truth
    (:func:`~monoavatar.bench.metrics.surface_metrics`), and after the similarity alone."""
    return ground_truth_error_map(body, shape, truth)[0]


def ground_truth_error_map(body: BodyModel, shape: CanonicalShape, truth: SynthGroundTruth
                           ) -> tuple[GroundTruthSummary, np.ndarray]:  # fmt: skip
    """:func:`ground_truth_error` and the (V,) distance (metres) of each avatar vertex to the
    ground-truth surface after both alignments (the heat map of ``monoavatar view``)."""
    mesh = truth.canonical_mesh(0)
    with torch.no_grad():
        _, joints = body.rest_shape(shape.shape.to(body.dtype)[None])
    rig = Rig(body.skin_weights.double().numpy(), joints[0].double().numpy(),
              tuple(body.parents))  # fmt: skip
    metrics, heat = surface_metrics(shape.vertices.double().numpy(), shape.faces.numpy(),
                                 np.asarray(mesh.vertices), np.asarray(mesh.faces),
                                 rig=rig)  # fmt: skip
    angles = metrics.bone_angles_deg
    worst = None if angles is None else int(np.nanargmax(angles))
    return GroundTruthSummary(
        surface_error_mm=metrics.mean_mm,
        surface_error_rigid_mm=float(metrics.rigid_mean_mm or metrics.mean_mm),
        bone_angle_median_deg=None if angles is None else float(np.nanmedian(angles)),
        bone_angle_max_deg=None if angles is None else float(np.nanmax(angles)),
        bone_angle_worst=None if worst is None else body.joint_names[worst],
    ), np.asarray(heat.errors, dtype=np.float64)
