"""The option checks every pipeline shares (:func:`monoavatar.pipelines.stages.check_options`)."""

from __future__ import annotations

import pytest
import torch

from monoavatar.pipelines.stages import PipelineError, check_options


def _check(checks: list[tuple[bool, str]], **kw: object) -> None:
    args: dict[str, object] = {"height": None, "focal": None, "perception": "auto",
                               "device": "cpu"} | kw  # fmt: skip
    check_options(checks, **args)  # type: ignore[arg-type]


def test_valid_options_pass() -> None:
    _check([(True, "never")], height=1.75, focal=800.0)


@pytest.mark.parametrize(("checks", "kw", "message"), [
    ([(False, "own check first")], {"height": 175.0}, "own check first"),
    ([], {"height": 175.0}, "--height is in metres (0.5 to 2.6), got 175.0; 175 cm is 1.75"),
    ([], {"focal": 0.0}, "--focal must be a positive number of pixels, got 0.0"),
    ([], {"perception": "openpose"}, "perception must be one of"),
    ([], {"device": "tpu"}, "--device must be cpu or cuda, got 'tpu'"),
])  # fmt: skip
def test_the_first_failed_check_is_the_message(checks: list[tuple[bool, str]],
                                               kw: dict[str, object], message: str) -> None:
    with pytest.raises(PipelineError) as info:
        _check(checks, **kw)
    assert message in str(info.value)


@pytest.mark.skipif(torch.cuda.is_available(), reason="the machine has a CUDA GPU")
def test_cuda_without_a_gpu_is_refused() -> None:
    with pytest.raises(PipelineError, match="no CUDA GPU"):
        _check([], device="cuda")
