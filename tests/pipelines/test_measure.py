"""``monoavatar measure`` on an avatar folder: the JSON and its units, the picture, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from monoavatar.body import load_body_model
from monoavatar.cli import main
from monoavatar.core.geometry import vertex_normals
from monoavatar.io.avatar_folder import AvatarFolder
from monoavatar.measure import MEASUREMENTS
from monoavatar.pipelines.measure import FORMAT, MeasureConfig, measure_folder
from tests.avatar_folders import make_params, make_report

CLOTHING = 0.01  # metres, along the normals


@pytest.fixture(scope="module")
def folders(tmp_path_factory: pytest.TempPathFactory) -> dict[bool, Path]:
    """Two folders of Anny's average body clothed by 1 cm: one metric, one up to scale."""
    body = load_body_model("anny")
    shape = body.default_shape()
    with torch.no_grad():
        rest, _ = body.rest_shape(shape)
    rest = rest[0].double()
    offsets = CLOTHING * vertex_normals(rest, body.faces).numpy()
    out = {}
    for known in (True, False):
        params = make_params(body.identity, shape[0].double().numpy(), offsets,
                             np.zeros((2, body.num_joints, 3)), scale_known=known)  # fmt: skip
        folder = AvatarFolder(params, make_report(2), rest.numpy() + offsets,
                              body.faces.numpy())  # fmt: skip
        path = tmp_path_factory.mktemp("avatar") / ("metric" if known else "scaleless")
        folder.save(path)
        out[known] = path
    return out


def test_metric_folder(folders: dict[bool, Path]) -> None:
    """With the body under the clothes as the avatar's own shape ('clamp': the offsets all point
    out), the clothing's 1 cm shows as 2 pi cm on every girth."""
    result = measure_folder(folders[True], config=MeasureConfig(under="clamp"))
    data = json.loads((folders[True] / "measurements.json").read_text())
    assert data["format"] == FORMAT and data["unit"] == "m" and data["scale_known"] is True
    assert [k for k in data if k in MEASUREMENTS] == list(MEASUREMENTS)
    for name in MEASUREMENTS:
        assert set(data[name]) == {"body", "clothed"}
        assert data[name]["body"] == pytest.approx(result.values[name]["body"])
    # Anny's average body is 1.63 m tall; the clothing adds about 2 pi d to the girths
    assert data["height"]["body"] == pytest.approx(1.627, abs=0.01)
    for name in ("chest", "waist", "hip", "thigh"):
        gain = data[name]["clothed"] - data[name]["body"]
        assert gain == pytest.approx(2 * np.pi * CLOTHING, rel=0.2), name
    picture = np.asarray(Image.open(folders[True] / "preview" / "measurements.png"))
    assert picture.shape[0] == 560 and picture.shape[1] > 2 * 560
    chest_red = (picture[..., 0] > 200) & (picture[..., 1] < 90) & (picture[..., 2] < 90)
    assert chest_red[:, :560].sum() > 50  # the chest girth is drawn on the front view


def test_folder_without_scale_reports_fractions_of_height(folders: dict[bool, Path],
                                                          tmp_path: Path) -> None:  # fmt: skip
    out = tmp_path / "m.json"
    measure_folder(folders[False], out, MeasureConfig(picture=False))
    data = json.loads(out.read_text())
    metric = measure_folder(folders[True], tmp_path / "metric.json",
                            MeasureConfig(picture=False)).values
    assert data["unit"] == "fraction of height" and data["scale_known"] is False
    assert "height" in data["note"] and "--height" in data["note"]
    assert data["height"]["body"] == pytest.approx(1.0, abs=1e-4)
    h = metric["height"]["body"]
    assert h is not None and metric["chest"]["body"] is not None
    assert data["chest"]["body"] == pytest.approx(metric["chest"]["body"] / h, abs=2e-4)
    assert not (folders[False] / "measurements.json").exists()  # --json elsewhere


def test_cli(folders: dict[bool, Path], capsys: pytest.CaptureFixture[str],
             tmp_path: Path) -> None:  # fmt: skip
    assert main(["measure", str(folders[True]), "--json", str(tmp_path / "x.json"),
                 "--no-picture"]) == 0
    out = capsys.readouterr().out
    assert "chest" in out and "(cm)" in out and str(tmp_path / "x.json") in out
    assert main(["measure", str(tmp_path / "nowhere")]) == 2
    assert "no such avatar folder" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:  # argparse refuses it
        main(["measure", str(folders[True]), "--under", "guess"])
    assert exit_info.value.code == 2 and "invalid choice" in capsys.readouterr().err
