from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from monoavatar.io import (
    CorruptFrameError,
    CorruptFrameWarning,
    EmptyVideoError,
    FrameSelection,
    InputFormatError,
    InputNotFoundError,
    input_label,
    load_image,
    read_frames,
    read_image,
    read_image_files,
    read_image_folder,
)


def _save(path: Path, value: int, size: tuple[int, int] = (12, 8), mode: str = "RGB") -> None:
    array = np.full((size[1], size[0], 3), value, np.uint8)
    Image.fromarray(array).convert(mode).save(path)


def test_folder_in_natural_order(tmp_path: Path) -> None:
    for k in (10, 2, 1):
        _save(tmp_path / f"frame{k}.png", 10 * k)
    (tmp_path / "notes.txt").write_text("ignored")
    frames = read_frames(tmp_path)
    np.testing.assert_array_equal(frames.images[:, 0, 0, 0], [10, 20, 100])
    np.testing.assert_array_equal(frames.indices, [0, 1, 2])
    assert frames.fps is None and np.all(np.isnan(frames.timestamps))


def test_folder_selection_and_fps(tmp_path: Path) -> None:
    for k in range(6):
        _save(tmp_path / f"{k:03d}.jpg", 40 * k)
    frames = read_image_folder(tmp_path, FrameSelection(step=2), fps=10.0)
    np.testing.assert_array_equal(frames.indices, [0, 2, 4])
    np.testing.assert_allclose(frames.timestamps, [0.0, 0.2, 0.4])
    timed = read_image_folder(tmp_path, FrameSelection(start_s=0.25), fps=10.0)
    np.testing.assert_array_equal(timed.indices, [3, 4, 5])
    with pytest.raises(ValueError, match="needs the folder's fps"):
        read_image_folder(tmp_path, FrameSelection(start_s=0.25))


def test_modes_are_converted_to_rgb(tmp_path: Path) -> None:
    _save(tmp_path / "grey.png", 77, mode="L")
    _save(tmp_path / "alpha.png", 99, mode="RGBA")
    Image.fromarray(np.full((4, 4), 60000, np.uint16)).save(tmp_path / "deep.png")
    assert load_image(tmp_path / "grey.png").shape == (8, 12, 3)
    assert load_image(tmp_path / "alpha.png")[0, 0].tolist() == [99, 99, 99]
    deep = load_image(tmp_path / "deep.png")
    assert deep.dtype == np.uint8 and deep[0, 0, 0] == 233


def test_exif_orientation_is_applied(tmp_path: Path) -> None:
    array = np.zeros((8, 12, 3), np.uint8)
    array[:4, :6] = 255  # white top-left quadrant
    image = Image.fromarray(array)
    exif = image.getexif()
    exif[0x0112] = 6  # "rotate 90° clockwise to display"
    image.save(tmp_path / "phone.jpg", exif=exif, quality=95)
    shown = load_image(tmp_path / "phone.jpg")
    assert shown.shape == (12, 8, 3)
    assert shown[:5, 5:].mean() > 200 and shown[:5, :3].mean() < 60  # now top-right


def test_single_image(tmp_path: Path) -> None:
    _save(tmp_path / "me.png", 5, size=(40, 20))
    frames = read_frames(tmp_path / "me.png")
    assert frames.images.shape == (1, 20, 40, 3)
    small = read_image(tmp_path / "me.png", max_side=20)
    assert small.images.shape == (1, 10, 20, 3)
    assert small.source_size == (40, 20) and small.scale == 0.5
    assert frames.source_size is None


def test_folder_downscaled_image_by_image(tmp_path: Path) -> None:
    for k in range(3):
        _save(tmp_path / f"{k}.png", k, size=(40, 20))
    frames = read_image_folder(tmp_path, max_side=20)
    assert frames.images.shape == (3, 10, 20, 3)
    assert frames.source_size == (40, 20) and frames.scale == 0.5
    assert read_image_folder(tmp_path, max_side=40).source_size is None


def test_corrupt_image_skipped_or_raised(tmp_path: Path) -> None:
    for k in range(3):
        _save(tmp_path / f"f{k}.png", 50 * k)
    (tmp_path / "f1.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    with pytest.warns(CorruptFrameWarning, match=r"unreadable image\(s\) \[1\]: f1\.png"):
        frames = read_image_folder(tmp_path)
    np.testing.assert_array_equal(frames.indices, [0, 2])
    with pytest.raises(CorruptFrameError, match=r"f1\.png") as info:
        read_image_folder(tmp_path, on_corrupt="raise")
    assert info.value.frames == [1]


def test_truncated_jpeg_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "cut.jpg"
    noise = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    Image.fromarray(noise).save(path, quality=90)
    path.write_bytes(path.read_bytes()[:400])
    with pytest.raises(InputFormatError, match=r"cut\.jpg: not a readable image"):
        load_image(path)


def test_folder_errors(tmp_path: Path) -> None:
    with pytest.raises(InputNotFoundError, match="no such folder"):
        read_image_folder(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(EmptyVideoError, match="holds no image"):
        read_frames(tmp_path / "empty")
    _save(tmp_path / "a1.png", 1, size=(12, 8))
    _save(tmp_path / "a2.png", 1, size=(10, 8))
    with pytest.raises(InputFormatError, match=r"a2\.png: image size 10x8 differs.*a1\.png"):
        read_image_folder(tmp_path)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "x.png").write_bytes(b"nope")
    with pytest.raises(EmptyVideoError, match="no selected image could be read"):
        read_image_folder(bad)


def test_image_files_in_natural_order_whatever_the_order_given(tmp_path: Path) -> None:
    """Several files are read like a folder: natural order of their names, a selection."""
    files = []
    for k in (10, 2, 1, 3):
        _save(tmp_path / f"img{k}.jpg", 10 * k)
        files.append(tmp_path / f"img{k}.jpg")
    (tmp_path / "img99.png").write_bytes(b"")  # not given: not read
    frames = read_frames(files)
    np.testing.assert_allclose(frames.images[:, 0, 0, 0], [10, 20, 30, 100], atol=2)
    np.testing.assert_array_equal(frames.indices, [0, 1, 2, 3])
    assert frames.source == str(tmp_path)
    two = read_image_files(files, FrameSelection(num_keyframes=2))
    assert len(two) == 2
    np.testing.assert_allclose(two.images[:, 0, 0, 0], [10, 100], atol=2)
    # one path in a list is that path
    assert len(read_frames([tmp_path / "img2.jpg"])) == 1
    assert input_label([str(f) for f in files]).endswith("(4 image files)")
    assert input_label(files[:1]) == str(files[0])


def test_image_files_errors(tmp_path: Path) -> None:
    _save(tmp_path / "a.png", 1)
    _save(tmp_path / "b.png", 2, size=(8, 12))  # portrait: another size
    (tmp_path / "clip.mp4").write_bytes(b"not a video")
    with pytest.raises(InputFormatError, match="differs from the first image a.png"):
        read_frames([tmp_path / "a.png", tmp_path / "b.png"])
    with pytest.raises(InputFormatError, match="must all be image files"):
        read_frames([tmp_path / "a.png", tmp_path / "clip.mp4"])
    with pytest.raises(InputFormatError, match="must all be image files"):
        read_frames([tmp_path / "a.png", tmp_path])  # a folder among them
    with pytest.raises(InputNotFoundError):
        read_frames([tmp_path / "a.png", tmp_path / "missing.png"])
    with pytest.raises(InputFormatError, match="given twice"):
        read_frames([tmp_path / "a.png", tmp_path / "." / "a.png"])
