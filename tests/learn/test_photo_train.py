"""``monoavatar train photo`` end to end at toy size: data, training and the exported weights,
with the garment-class network; a second run resumes to the same weights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from monoavatar.learn.photo_data import CLASS_CHANNELS, PhotoDataset, PhotoDataSettings
from monoavatar.learn.photo_model import PhotoNetworkSettings, load_photo_network
from monoavatar.learn.photo_train import PhotoTrainConfig, train_photo
from monoavatar.learn.training import TrainSettings
from monoavatar.learn.weights import load_weights


def _config() -> PhotoTrainConfig:
    return PhotoTrainConfig(
        samples=3, val=1, fit_photos=0, workers=1, progress=False,
        data=PhotoDataSettings(map_size=64, image_size=128, texture_size=128),
        network=PhotoNetworkSettings(base=4, depth=5, max_channels=8, map_size=64,
                                     classes=True),
        train=TrainSettings(steps=3, batch=2, gan_weight=0.0, dssim_scales=2,
                            checkpoint_every=2, validate_every=3),
    )  # fmt: skip


def test_train_photo_with_classes_end_to_end(anny32, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]  # noqa: E501
    result = train_photo(tmp_path, _config())
    assert result.train.finished and result.train.steps_done == 3
    assert 0.0 <= result.train.history[-1]["val_class_accuracy"] <= 1.0
    network = load_photo_network(anny32, result.weights)
    assert network.settings.classes
    data = PhotoDataset(sorted((tmp_path / "data").glob("train-*.npz")))
    assert data.classes.shape[1] == CLASS_CHANNELS
    # the priors shipped in the weights are the training photos' class means
    assert torch.equal(network.generator.state_dict()["class_means"], data.class_means())
    maps = network.predict(np.zeros((64, 64, 3), np.float32), np.zeros((64, 64), bool))
    assert maps.shape == (64, 64, 6) and np.isfinite(maps).all()
    tensors, meta = load_weights(result.weights)
    again = train_photo(tmp_path, _config())  # everything is there: nothing is redone
    assert again.train.steps_done == 3
    tensors2, meta2 = load_weights(again.weights)
    assert tensors.keys() == tensors2.keys()
    assert all(torch.equal(tensors[k], tensors2[k]) for k in tensors)
