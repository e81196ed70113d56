"""``monoavatar train photo``: everything that makes the shipped photo-network weights, from
nothing but our own ``synth``.

Steps, each resumable (a second run with the same folder continues where the first stopped)::

    DIR/fit_error.json     the single-image fitter's error on synthetic photos (measured)
    DIR/data/              training, validation and test samples (shards, data.json)
    DIR/train/             the training loop's checkpoint.safetensors and log.jsonl
    DIR/photo.safetensors  the generator's weights, as shipped in monoavatar/learn/weights/
    DIR/curve.png          validation error against training time

The same configuration gives the same weights (seeded data, seeded training; see
:mod:`monoavatar.learn.training`).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.files import atomic_write_text
from monoavatar.learn.photo_data import (
    FitError,
    PhotoDataset,
    PhotoDataSettings,
    generate_photo_data,
)
from monoavatar.learn.photo_model import PhotoNetworkSettings
from monoavatar.learn.training import TrainResult, TrainSettings, export_generator, train

__all__ = ["PhotoTrainConfig", "PhotoTrainResult", "train_photo"]

FIT_ERROR_SEEDS = 3_000_000
"""Photos the fitter's error is measured on are drawn from seeds from here (disjoint from
the train, validation and test seeds)."""


class TrainError(MonoavatarError, ValueError):
    """Invalid training options."""


def _default_train() -> TrainSettings:
    return TrainSettings(steps=2000, batch=4, gan_weight=0.0, checkpoint_every=250,
                         validate_every=250)


@dataclass
class PhotoTrainConfig:
    """Options of ``monoavatar train photo`` (the CLI's options are derived from these).

    Attributes:
        samples: training photos; val: validation photos (other subjects); test: test photos
            written for the benchmark's sealed split (never seen in training).
        fit_photos: photos the fitter's error is measured on; 0 trains on exact poses
            (the ablation "ground-truth poses").
        workers: processes that make the data.
        data: how the photos are drawn; network: the generator's size; train: the loop.
        max_minutes: stop the training loop (resumably) after this many minutes.
        progress: progress bars.
    """

    samples: int = 1000
    val: int = 50
    test: int = 0
    fit_photos: int = 16
    workers: int = 2
    data: PhotoDataSettings = field(default_factory=PhotoDataSettings)
    network: PhotoNetworkSettings = field(default_factory=PhotoNetworkSettings)
    train: TrainSettings = field(default_factory=_default_train)
    max_minutes: float | None = None
    progress: bool = True

    def validate(self) -> None:
        if self.samples < 1 or self.val < 1 or self.test < 0:
            raise TrainError(f"--samples and --val must be at least 1, got {self.samples}, "
                             f"{self.val}")  # fmt: skip
        if self.fit_photos < 0 or self.workers < 1:
            raise TrainError("--fit-photos must be >= 0 and --workers >= 1")
        if self.network.map_size != self.data.map_size:
            raise TrainError("the network's and the data's map sizes differ")
        self.data.validate()
        self.train.validate()


@dataclass
class PhotoTrainResult:
    """Where the weights are, the training loop's result, and the seconds per step."""

    weights: Path
    train: TrainResult
    seconds: dict[str, float]


def fit_error_of(folder: Path, config: PhotoTrainConfig) -> FitError:
    """``fit_error.json``: measured once (on ``fit_photos`` photos), then read back."""
    from monoavatar.body import load_body_model
    from monoavatar.learn.fit_error import measure_fit_error

    path = folder / "fit_error.json"
    if path.is_file():
        record = json.loads(path.read_text())
        if record.get("photos") == config.fit_photos:
            return FitError.from_json(record)
    if config.fit_photos == 0:
        error = FitError.none(load_body_model("anny").num_joints)
    else:
        seeds = list(range(FIT_ERROR_SEEDS, FIT_ERROR_SEEDS + config.fit_photos))
        error = measure_fit_error(load_body_model("anny"), load_body_model("anny-local"), seeds,
                                  config.data, progress=config.progress)  # fmt: skip
    error = replace(error, photos=config.fit_photos)
    atomic_write_text(path, json.dumps(error.to_json(), indent=1))
    return error


def train_photo(folder: str | Path, config: PhotoTrainConfig | None = None) -> PhotoTrainResult:
    """Measure the fitter's error, make the data, train, export ``photo.safetensors``."""
    import torch

    config = config or PhotoTrainConfig()
    config.validate()
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    error = fit_error_of(out, config)
    seconds["fit_error"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    counts = {"train": config.samples, "val": config.val}
    if config.test:
        counts["test"] = config.test
    shards = generate_photo_data(out / "data", counts, config.data, error, config.workers,
                                 config.progress)  # fmt: skip
    seconds["data"] = time.perf_counter() - t0
    classes = config.network.classes
    train_set = PhotoDataset(shards["train"][: -(-config.samples // 25)], classes)
    val_set = PhotoDataset(shards["val"][: -(-config.val // 25)], classes)
    if config.network.tangential_scale is not None:
        from monoavatar.body import load_body_model
        from monoavatar.learn.photo_data import template_frames
        from monoavatar.learn.uvmaps import uv_layout

        body = load_body_model("anny")
        frames = template_frames(body, uv_layout(body, config.data.map_size))
        for dataset in (train_set, val_set):
            dataset.to_normal_frame(frames, config.network.tangential_scale)
    torch.manual_seed(config.train.seed)
    prior = train_set.class_means() if classes else train_set.mean_target()
    generator = config.network.build(prior)
    settings = replace(config.train, class_channels=config.network.class_channels)
    t0 = time.perf_counter()
    max_seconds = None if config.max_minutes is None else 60.0 * config.max_minutes
    result = train(generator, train_set, val_set, settings, out / "train",
                   progress=config.progress,
                   max_seconds=max_seconds)  # fmt: skip
    seconds["train"] = time.perf_counter() - t0
    meta = dict(config.network.metadata())
    meta.update({
        "trained": json.dumps({"samples": config.samples, "val": config.val,
                               "fit_photos": config.fit_photos, "data": asdict(config.data),
                               "train": asdict(settings), "steps_done": result.steps_done,
                               "finished": result.finished}),
        "validation": json.dumps(result.val or {}),
    })  # fmt: skip
    weights = out / "photo.safetensors"
    export_generator(generator, weights, meta)
    _curve(out / "train" / "log.jsonl", out / "curve.png")
    return PhotoTrainResult(weights, result, seconds)


def _curve(log: Path, path: Path) -> None:
    """Validation error against training time, as a PNG (nothing when the log is empty)."""
    if not log.is_file():
        return
    rows = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
    rows = [r for r in rows if "val_l1" in r]
    if not rows:
        return
    from monoavatar.io.plots import line_plot

    minutes = [r["seconds"] / 60.0 for r in rows]
    line_plot(path, {"validation L1 (maps)": (minutes, [r["val_l1"] for r in rows])},
              "training time (minutes)", "masked L1 of the maps", "photo network")
