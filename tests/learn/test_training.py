"""The training loop: same seed, same weights; a run interrupted and resumed ends bit for bit
where an uninterrupted one does; the time limit, the log, the checkpoint's contents, the
settings' errors, and exported generator weights."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import Tensor, nn
from torch.utils.data import Dataset

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.threads import torch_threads
from monoavatar.learn.networks import PatchDiscriminator, UNet
from monoavatar.learn.training import (
    CHECKPOINT_NAME,
    LOG_NAME,
    TrainError,
    TrainResult,
    TrainSettings,
    evaluate,
    export_generator,
    load_generator,
    train,
)
from monoavatar.learn.weights import WeightsError, load_weights


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    """Tiny tensors: one PyTorch thread (a second one would only wait for a busy core)."""
    with torch_threads(1):
        yield


class _Maps(Dataset[dict[str, Tensor]]):
    """``count`` fixed samples of 16×16: 2 input channels, a smooth 1-channel target made
    from them, a weight mask with a zero corner."""

    def __init__(self, count: int, seed: int, size: int = 16) -> None:
        gen = torch.Generator().manual_seed(seed)
        self.x = torch.randn(count, 2, size, size, generator=gen)
        blur = nn.functional.avg_pool2d(self.x, 3, stride=1, padding=1)
        self.y = torch.tanh(blur[:, :1] * blur[:, 1:])
        self.w = torch.ones(count, 1, size, size)
        self.w[:, :, : size // 4, : size // 4] = 0.0

    def __len__(self) -> int:
        return len(self.x)

    def __getitem__(self, i: int) -> dict[str, Tensor]:
        return {"input": self.x[i], "target": self.y[i], "weight": self.w[i]}


class _NoisyMaps(_Maps):
    """_Maps with noise drawn from PyTorch's global generator on every read (an
    augmentation), which training must seed and checkpoint."""

    def __getitem__(self, i: int) -> dict[str, Tensor]:
        sample = super().__getitem__(i)
        return {**sample, "input": sample["input"] + 0.1 * torch.randn(sample["input"].shape)}


def _settings(**changes: object) -> TrainSettings:
    base = TrainSettings(steps=7, batch=2, lr=1e-3, seed=3, dssim_scales=2, gan_weight=0.05,
                         checkpoint_every=2, validate_every=3, val_batch=3)  # fmt: skip
    return replace(base, **changes)  # type: ignore[arg-type]


def _generator() -> UNet:
    torch.manual_seed(0)
    return UNet(2, 1, base=4, depth=2)


def _discriminator() -> PatchDiscriminator:
    torch.manual_seed(1)
    return PatchDiscriminator(3, base=4, layers=1)


def _run(
    out: Path,
    settings: TrainSettings,
    max_seconds: float | None = None,
    gan: bool = True,
    noisy: bool = False,
) -> tuple[UNet, nn.Module | None, TrainResult]:
    generator = _generator()
    disc = _discriminator() if gan else None
    data = _NoisyMaps(5, seed=0) if noisy else _Maps(5, seed=0)
    result = train(generator, data, _Maps(4, seed=1), settings, out,
                   discriminator=disc, progress=False, max_seconds=max_seconds)  # fmt: skip
    return generator, result.discriminator, result


def _same_weights(a: nn.Module, b: nn.Module) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


def _without_seconds(history: list[dict[str, float]]) -> list[dict[str, float]]:
    return [{k: v for k, v in e.items() if k != "seconds"} for e in history]


def test_the_same_seed_gives_the_same_weights(tmp_path: Path) -> None:
    g1, d1, r1 = _run(tmp_path / "a", _settings())
    g2, d2, r2 = _run(tmp_path / "b", _settings())
    assert d1 is not None and d2 is not None
    assert _same_weights(g1, g2) and _same_weights(d1, d2)
    assert _without_seconds(r1.history) == _without_seconds(r2.history)
    g3, _, _ = _run(tmp_path / "c", _settings(seed=4))  # another batch order
    assert not _same_weights(g1, g3)
    assert not _same_weights(g1, _generator())  # it did train


def test_interrupted_and_resumed_equals_uninterrupted(tmp_path: Path) -> None:
    whole, whole_d, whole_result = _run(tmp_path / "whole", _settings(), noisy=True)
    # One step per call (a limit of 0 s stops after the first step), each call with fresh
    # modules, as a new process would start: 7 interruptions.
    out = tmp_path / "pieces"
    calls = 0
    while True:
        generator, disc, result = _run(out, _settings(), max_seconds=0.0, noisy=True)
        calls += 1
        if result.finished:
            break
        assert result.steps_done == calls
    assert calls == 7
    assert disc is not None and whole_d is not None
    assert _same_weights(generator, whole) and _same_weights(disc, whole_d)
    assert _without_seconds(result.history) == _without_seconds(whole_result.history)
    log = [json.loads(line) for line in (out / LOG_NAME).read_text().splitlines()]
    assert _without_seconds(log) == _without_seconds(whole_result.history)
    assert [e["step"] for e in log] == [3, 6, 7]
    seconds = [e["seconds"] for e in log]
    assert seconds == sorted(seconds)  # cumulative over the calls

    # Raising the step count continues a finished run, like one that had that count.
    shorter = tmp_path / "shorter"
    _run(shorter, _settings(steps=4), noisy=True)
    longer, _, _ = _run(shorter, _settings(steps=7), noisy=True)
    assert _same_weights(longer, whole)


def test_a_crash_after_the_checkpoint_replays_the_same_steps(tmp_path: Path) -> None:
    """The log keeps only what the checkpoint has seen: entries of steps after it (written
    by a run that died before its next checkpoint) are dropped and written again."""
    whole, _, whole_result = _run(tmp_path / "whole", _settings())
    out = tmp_path / "crash"
    for _ in range(4):  # checkpoint at step 4, log entry at step 3
        _run(out, _settings(), max_seconds=0.0)
    with open(out / LOG_NAME, "a") as fh:  # a dead run's entry of step 6, and half a line
        fh.write(json.dumps({"step": 6, "seconds": 1.0, "val_l1": 9.0}) + '\n{"step": 7,')
    generator, _, result = _run(out, _settings())
    assert _same_weights(generator, whole)
    assert _without_seconds(result.history) == _without_seconds(whole_result.history)


def test_loader_workers_do_not_change_the_result(tmp_path: Path) -> None:
    one, _, _ = _run(tmp_path / "a", _settings(steps=3))
    two, _, _ = _run(tmp_path / "b", _settings(steps=3, workers=1))
    assert _same_weights(one, two)


def test_the_time_limit_checkpoints_and_reports_unfinished(tmp_path: Path) -> None:
    generator, _, result = _run(tmp_path, _settings(steps=50), max_seconds=0.0)
    assert result.finished is False and result.steps_done == 1
    tensors, meta = load_weights(tmp_path / CHECKPOINT_NAME)
    assert meta["step"] == "1" and meta["content"] == "checkpoint"
    for name, value in generator.state_dict().items():
        assert torch.equal(tensors[f"generator/{name}"], value)
    kinds = {name.split("/")[0] for name in tensors}
    assert kinds == {"generator", "discriminator", "opt_g", "opt_d", "rng"}
    assert result.seconds > 0


def test_the_log_holds_the_validations(tmp_path: Path) -> None:
    generator, _, result = _run(tmp_path, _settings())
    log = [json.loads(line) for line in (tmp_path / LOG_NAME).read_text().splitlines()]
    assert [e["step"] for e in log] == [3, 6, 7]
    for entry in log:
        assert {"seconds", "train_loss", "train_l1", "train_dssim", "train_gan", "train_d",
                "val_l1", "val_ms_dssim"} <= entry.keys()  # fmt: skip
    assert log == result.history
    # The last validation is of the final weights; L1 recomputed here from the definition.
    val = _Maps(4, seed=1)
    with torch.no_grad():
        out = generator(val.x)
    m, d = val.w.numpy(), np.abs(out.numpy() - val.y.numpy())
    assert log[-1]["val_l1"] == pytest.approx((m * d).sum() / m.sum(), rel=1e-5)
    assert result.val == evaluate(generator, val, batch=3, scales=2)
    # The train L1 of an entry is the mean over the steps since the previous entry.
    assert 0 < log[0]["train_l1"] and log[0]["train_loss"] > log[0]["train_l1"]


def test_no_discriminator_without_the_adversarial_term(tmp_path: Path) -> None:
    generator, disc, result = _run(tmp_path, _settings(gan_weight=0.0), gan=False)
    assert disc is None
    tensors, _ = load_weights(tmp_path / CHECKPOINT_NAME)
    assert {name.split("/")[0] for name in tensors} == {"generator", "opt_g", "rng"}
    assert "train_gan" not in result.history[0] and "train_d" not in result.history[0]
    with pytest.raises(TrainError, match="gan_weight is 0"):
        _run(tmp_path / "x", _settings(gan_weight=0.0), gan=True)


def test_a_default_discriminator_is_built_from_the_seed(tmp_path: Path) -> None:
    def run(out: Path) -> nn.Module | None:
        settings = _settings(steps=1, dssim_scales=3)
        return train(_generator(), _Maps(3, 0, size=32), None, settings, out,
                     progress=False).discriminator  # fmt: skip

    d1, d2 = run(tmp_path / "a"), run(tmp_path / "b")
    assert isinstance(d1, PatchDiscriminator) and d1.in_channels == 3
    assert d2 is not None and _same_weights(d1, d2)


def test_the_callers_random_state_is_left_alone(tmp_path: Path) -> None:
    generator, disc = _generator(), _discriminator()
    torch.manual_seed(123)
    before = torch.get_rng_state()
    train(generator, _Maps(5, 0), None, _settings(steps=2), tmp_path, disc, progress=False)
    assert torch.equal(torch.get_rng_state(), before)


def test_bad_settings_and_devices_are_refused(tmp_path: Path) -> None:
    with pytest.raises(TrainError, match="batch must be at least 1.*betas must be") as info:
        _settings(batch=0, betas=(0.5, 1.5)).validate()
    assert isinstance(info.value, MonoavatarError)
    with pytest.raises(TrainError, match="not all 0"):
        _settings(l1_weight=0.0, dssim_weight=0.0, gan_weight=0.0).validate()
    with pytest.raises(TrainError, match="device must be"):
        _settings(device="tpu").validate()
    if not torch.cuda.is_available():
        with pytest.raises(TrainError, match="CUDA is not available"):
            _run(tmp_path / "cuda", _settings(device="cuda"))
        with pytest.raises(TrainError, match="CUDA is not available"):
            evaluate(_generator(), _Maps(2, 0), device="cuda:0")
    with pytest.raises(TrainError, match="max_seconds"):
        _run(tmp_path / "t", _settings(), max_seconds=-1.0)


def test_a_checkpoint_of_other_settings_is_refused(tmp_path: Path) -> None:
    _run(tmp_path, _settings(steps=2))
    with pytest.raises(TrainError, match=r"other settings \(lr 0.001 -> 0.002\)"):
        _run(tmp_path, _settings(steps=4, lr=2e-3))
    generator = UNet(2, 1, base=8, depth=2)  # another architecture
    with pytest.raises(WeightsError, match="do not fit UNet"):
        train(generator, _Maps(5, 0), None, _settings(steps=4), tmp_path,
              discriminator=_discriminator(), progress=False)  # fmt: skip


def test_bad_samples_are_refused(tmp_path: Path) -> None:
    class Broken(_Maps):
        def __getitem__(self, i: int) -> dict[str, Tensor]:
            return {"input": self.x[i], "target": self.y[i]}

    with pytest.raises(TrainError, match="'weight'"):
        train(_generator(), Broken(3, 0), None, _settings(), tmp_path, _discriminator(),
              progress=False)  # fmt: skip


def test_exported_generator_weights_load_strictly(tmp_path: Path) -> None:
    generator = _generator()
    path = tmp_path / "g.safetensors"
    export_generator(generator, path, {"architecture": "unet-4-2"})
    torch.manual_seed(5)
    other = UNet(2, 1, base=4, depth=2)
    assert not _same_weights(other, generator)
    assert load_generator(other, path) == {"architecture": "unet-4-2"}
    assert _same_weights(other, generator)
    with pytest.raises(WeightsError, match="do not fit UNet: .*shape of"):
        load_generator(UNet(2, 3, base=4, depth=2), path)
    with pytest.raises(WeightsError, match="missing"):
        load_generator(UNet(2, 1, base=4, depth=3), path)
    _run(tmp_path / "run", _settings(steps=1))
    with pytest.raises(WeightsError, match="not exported generator weights"):
        load_generator(other, tmp_path / "run" / CHECKPOINT_NAME)
    with pytest.raises(WeightsError, match="reserved"):
        export_generator(generator, path, {"content": "x"})


class _Classes(_Maps):
    """_Maps whose pixels are of class 1 where the first input channel is positive, else of
    class 0; the target is the class's value (0.5 or −0.5), followed by the one-hot classes."""

    def __getitem__(self, i: int) -> dict[str, Tensor]:
        sample = super().__getitem__(i)
        positive = (sample["input"][:1] > 0).float()
        target = torch.cat([positive - 0.5, 1.0 - positive, positive])
        return {**sample, "target": target}


def test_class_channels_are_learned_by_cross_entropy_and_kept_out_of_the_map_errors(
        tmp_path: Path) -> None:  # fmt: skip
    """A ClassMixture over the two classes' values learns the per-pixel class (validation
    accuracy from about chance to above 0.8: pixels near 0 stay ambiguous), and its maps with
    it; evaluate's L1 is that of the map channel alone, computed here by hand."""
    from monoavatar.learn.networks import ClassMixture

    means = torch.tensor([-0.5, 0.5]).view(2, 1, 1, 1).expand(2, 1, 16, 16)
    torch.manual_seed(0)
    generator = ClassMixture(UNet(2, 1 + 2, base=4, depth=2), means)
    val = _Classes(4, seed=1)
    before = evaluate(generator, val, scales=2, classes=2)
    settings = _settings(steps=200, gan_weight=0.0, dssim_weight=0.0, class_channels=2,
                         validate_every=200, checkpoint_every=200, lr=1e-2)  # fmt: skip
    train(generator, _Classes(8, seed=0), val, settings, tmp_path, progress=False)
    after = evaluate(generator, val, scales=2, classes=2)
    assert before["class_accuracy"] < 0.65 and after["class_accuracy"] > 0.8
    assert after["l1"] < 0.5 * before["l1"]
    with torch.no_grad():
        batch = [val[i] for i in range(len(val))]
        x = torch.stack([b["input"] for b in batch])
        y, w = torch.stack([b["target"] for b in batch]), torch.stack([b["weight"] for b in batch])
        out = generator(x)
    by_hand = float((w * (out[:, :1] - y[:, :1]).abs()).sum() / w.sum())
    assert after["l1"] == pytest.approx(by_hand, rel=1e-5)
    log = [json.loads(line) for line in (tmp_path / LOG_NAME).read_text().splitlines()]
    assert "train_class" in log[-1] and log[-1]["val_class_accuracy"] == after["class_accuracy"]
