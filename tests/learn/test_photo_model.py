"""The photo network as shipped: architecture in the weights' metadata, the residual over the
mean maps, loading (and refusing) weights, inference shapes."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from monoavatar.learn.networks import ResidualOverMean
from monoavatar.learn.photo_model import (
    PhotoModelError,
    PhotoNetworkSettings,
    default_weights,
    load_photo_network,
)
from monoavatar.learn.training import export_generator

SMALL = PhotoNetworkSettings(base=4, depth=5, max_channels=8, map_size=64, residual_scale=0.1,
                             classes=False)  # fmt: skip


def test_residual_starts_at_the_mean_and_saves_it() -> None:
    torch.manual_seed(0)
    mean = torch.randn(6, 64, 64)
    net = SMALL.build(mean)
    assert isinstance(net, ResidualOverMean)
    for p in net.net.parameters():
        torch.nn.init.zeros_(p)
    x = torch.randn(2, 7, 64, 64)
    assert torch.equal(net(x), mean.expand(2, -1, -1, -1))
    assert torch.equal(net.state_dict()["mean"], mean)


def test_metadata_round_trip() -> None:
    assert PhotoNetworkSettings.from_metadata(SMALL.metadata()) == SMALL
    normal = replace(SMALL, tangential_scale=0.25)
    assert PhotoNetworkSettings.from_metadata(normal.metadata()) == normal
    classes = replace(SMALL, classes=True)
    assert PhotoNetworkSettings.from_metadata(classes.metadata()) == classes
    with pytest.raises(PhotoModelError, match="architecture"):
        PhotoNetworkSettings.from_metadata({"format": "x"})


def test_load_predict_and_refuse(anny32, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    torch.manual_seed(1)
    mean = torch.randn(6, 64, 64)
    path = tmp_path / "small.safetensors"
    export_generator(SMALL.build(mean), path, SMALL.metadata())
    network = load_photo_network(anny32, path)
    assert torch.equal(network.generator.state_dict()["mean"], mean)  # the prior came back
    maps, probabilities = network.infer(np.zeros((64, 64, 3), np.float32),
                                        np.zeros((64, 64), bool))  # fmt: skip
    assert maps.shape == (64, 64, 6) and probabilities is None  # no classes
    assert np.all(maps[~network.layout.chart] == 0)
    with pytest.raises(PhotoModelError, match="no photo-network weights"):
        load_photo_network(anny32, tmp_path / "missing.safetensors")


def test_normal_frame_predictions_come_back_canonical(anny32, tmp_path: Path
                                                      ) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
    """A network predicting in the normal frame (its prior: 0.4 along the normal, 0.1 along the
    first tangent, scaled by 0.5): predict() returns canonical vectors 0.4 n + 0.2 t1."""
    from monoavatar.learn.photo_data import template_frames

    settings = replace(SMALL, tangential_scale=0.5)
    mean = torch.zeros(6, 64, 64)
    mean[0], mean[1] = 0.4, 0.1
    net = settings.build(mean)
    for p in net.net.parameters():
        torch.nn.init.zeros_(p)
    path = tmp_path / "normal.safetensors"
    export_generator(net, path, settings.metadata())
    network = load_photo_network(anny32, path)
    assert network.frames is not None
    maps = network.predict(np.zeros((64, 64, 3), np.float32), np.zeros((64, 64), bool))
    frames = template_frames(anny32, network.layout)
    chart = network.layout.chart
    expected = 0.4 * frames[chart, 0] + 0.2 * frames[chart, 1]
    np.testing.assert_allclose(maps[chart, :3], expected, atol=1e-5)


def test_a_class_network_predicts_its_recognised_classs_maps(anny32, tmp_path: Path
                                                             ) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
    """Class priors M_k (k + 1 everywhere) and a network whose head answers class 2 (its bias):
    predict() gives M_2's six channels, not the logits; infer() the class probabilities, one-hot
    on class 2 inside the charts and zero outside; the priors load back."""
    settings = replace(SMALL, classes=True)
    means = torch.arange(1.0, 6.0).view(5, 1, 1, 1).expand(5, 6, 64, 64).clone()
    net = settings.build(means)
    for p in net.net.parameters():
        torch.nn.init.zeros_(p)
    with torch.no_grad():
        net.net.head.bias[6 + 2] = 30.0
    path = tmp_path / "classes.safetensors"
    export_generator(net, path, settings.metadata())
    network = load_photo_network(anny32, path)
    assert torch.equal(network.generator.state_dict()["class_means"], means)
    maps = network.predict(np.zeros((64, 64, 3), np.float32), np.zeros((64, 64), bool))
    assert maps.shape == (64, 64, 6)
    np.testing.assert_allclose(maps[network.layout.chart], 3.0, atol=1e-5)
    same, probabilities = network.infer(np.zeros((64, 64, 3), np.float32),
                                        np.zeros((64, 64), bool))  # fmt: skip
    np.testing.assert_array_equal(same, maps)
    assert probabilities is not None and probabilities.shape == (64, 64, 5)
    chart = network.layout.chart
    np.testing.assert_allclose(probabilities[chart], np.eye(5)[[2]].repeat(chart.sum(), 0),
                               atol=1e-6)  # fmt: skip
    assert np.all(probabilities[~chart] == 0)


def test_shipped_weights_load(anny32) -> None:  # type: ignore[no-untyped-def]
    """The repository ships weights that load into the architecture they name."""
    assert default_weights().is_file()
    network = load_photo_network(anny32)
    assert network.settings.map_size == 256
    assert "trained" in network.metadata
