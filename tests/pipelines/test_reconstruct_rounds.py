"""The analysis-by-synthesis loop of ``reconstruct`` (``fit_avatar``): which stage runs when,
with which settings (the stages themselves are stand-ins here)."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import pytest

from monoavatar.pipelines import reconstruct as rec
from monoavatar.pipelines.stages import InputSettings, PipelineError, StageTimer


def _record_stages(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, Any]]:
    calls: list[tuple[str, Any]] = []

    def pose_stage(body, inputs, settings, *, poses, progress):
        calls.append(("poses", None))
        return "track"

    def shape_stage(body, inputs, track, settings):
        calls.append(("shape", None))
        return track, "shape"

    def texture_stage(body, inputs, track, shape, settings, *, progress):
        calls.append(("texture", settings.register_rounds))
        return "texture", "sh"

    def flow_stage(body, inputs, track, shape, texture, sh, settings, pose, *, progress):
        calls.append(("flow", None))
        return track

    for name, fn in [("pose_stage", pose_stage), ("shape_stage", shape_stage),
                     ("texture_stage", texture_stage), ("flow_stage", flow_stage)]:  # fmt: skip
        monkeypatch.setattr(rec, name, fn)
    return calls


def test_textures_between_flow_rounds_take_their_own_registration_rounds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls = _record_stages(monkeypatch)
    base = rec.ReconstructConfig(progress=False)
    config = replace(base, flow_rounds=3, round_register_rounds=0,
                     texture=replace(base.texture, register_rounds=2))  # fmt: skip
    rec.fit_avatar(SimpleNamespace(), SimpleNamespace(), config, StageTimer())
    assert [c[0] for c in calls] == ["poses", "shape", "texture"] + ["flow", "shape", "texture"] * 3
    assert [c[1] for c in calls if c[0] == "texture"] == [0, 0, 0, 2]  # the last one: full

    calls.clear()  # None: every texture as the final one
    every = replace(config, round_register_rounds=None)
    rec.fit_avatar(SimpleNamespace(), SimpleNamespace(), every, StageTimer())
    assert [c[1] for c in calls if c[0] == "texture"] == [2, 2, 2, 2]

    calls.clear()  # no flow rounds: the only texture is the final one
    rec.fit_avatar(SimpleNamespace(), SimpleNamespace(), replace(config, flow_rounds=0),
                   StageTimer())  # fmt: skip
    assert calls == [("poses", None), ("shape", None), ("texture", 2)]

    calls.clear()  # ground-truth poses get no flow rounds either
    gt = replace(config, input=InputSettings(poses="ground-truth"))
    rec.fit_avatar(SimpleNamespace(), SimpleNamespace(), gt, StageTimer())
    assert [c for c in calls if c[0] == "texture"] == [("texture", 2)]


def test_negative_round_registration_is_refused() -> None:
    with pytest.raises(PipelineError, match="--round-register-rounds"):
        rec.ReconstructConfig(round_register_rounds=-1).validate()
