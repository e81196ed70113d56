from __future__ import annotations

import warnings
from pathlib import Path

import av
import numpy as np
import pytest

from monoavatar.io import (
    CorruptFrameError,
    CorruptFrameWarning,
    EmptyVideoError,
    FrameSelection,
    InputNotFoundError,
    NotAVideoError,
    TruncatedVideoError,
    count_video_frames,
    read_frames,
    read_video,
)
from tests.io.media_helpers import frame_number, set_mp4_matrix, write_video


def _numbers(images: np.ndarray) -> list[int]:
    return [frame_number(im) for im in images]


@pytest.mark.parametrize(
    ("name", "codec"),
    [("a.mp4", "libx264"), ("a.mov", "libx264"), ("a.avi", "mpeg4"), ("a.webm", "libvpx-vp9")],
)
def test_reads_every_container(tmp_path: Path, name: str, codec: str) -> None:
    path = write_video(tmp_path / name, n=6, codec=codec)
    frames = read_frames(path)
    assert frames.images.shape == (6, 48, 64, 3)
    assert frames.images.dtype == np.uint8
    assert _numbers(frames.images) == list(range(6))
    np.testing.assert_array_equal(frames.indices, np.arange(6))
    np.testing.assert_allclose(frames.timestamps, np.arange(6) / 25.0, atol=1e-3)
    assert frames.fps == pytest.approx(25.0)
    assert frames.source == str(path)
    # the top-left quadrant is white: no rotation was applied
    assert frames.images[0, :20, :28].mean() > 240
    assert count_video_frames(path) == 6


def test_rgb_channel_order(tmp_path: Path) -> None:
    path = tmp_path / "red.mp4"
    container = av.open(str(path), "w")
    stream = container.add_stream("libx264", rate=10)
    stream.width, stream.height, stream.pix_fmt = 32, 32, "yuv420p"
    red = np.zeros((32, 32, 3), np.uint8)
    red[..., 0] = 220
    for packet in stream.encode(av.VideoFrame.from_ndarray(red, format="rgb24")):
        container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()
    image = read_video(path).images[0].astype(float)
    assert image[..., 0].mean() > 180 and image[..., 2].mean() < 40


@pytest.mark.parametrize(
    ("rotation", "corner"),
    [
        (None, "top_left"),
        (-90, "top_right"),  # rotate clockwise to display (a phone's portrait video)
        (90, "bottom_left"),
        (180, "bottom_right"),
    ],
)
def test_rotation_metadata_is_applied(tmp_path: Path, rotation: int | None, corner: str) -> None:
    path = write_video(tmp_path / "rot.mp4", n=3, width=64, height=48, rotation=rotation)
    images = read_video(path).images
    rotated = rotation in (90, -90)
    assert images.shape[1:3] == ((64, 48) if rotated else (48, 64))
    h, w = images.shape[1:3]
    quadrants = {
        "top_left": images[0, : h // 2 - 2, : w // 2 - 2],
        "top_right": images[0, : h // 2 - 2, w // 2 + 2 :],
        "bottom_left": images[0, h // 2 + 2 :, : w // 2 - 2],
        "bottom_right": images[0, h // 2 + 2 :, w // 2 + 2 :],
    }
    assert quadrants[corner].mean() > 240
    assert all(q.mean() < 100 for name, q in quadrants.items() if name != corner)


def test_rotation_written_by_another_muxer(tmp_path: Path) -> None:
    """The matrix QuickTime/iPhones write for portrait video (rotate 90° clockwise to show)."""
    path = write_video(tmp_path / "phone.mp4", n=2, width=64, height=48)
    set_mp4_matrix(path, (0, 0x10000, 0, 0xFFFF0000, 0, 0, 48 << 16, 0, 0x40000000))
    image = read_video(path).images[0]
    assert image.shape == (64, 48, 3)
    assert image[:28, 26:].mean() > 240  # the coded top-left is now at the top right
    assert image[:28, :22].mean() < 100


def test_step_selection(make_video) -> None:
    frames = read_video(make_video(n=10), FrameSelection(step=3))
    np.testing.assert_array_equal(frames.indices, [0, 3, 6, 9])
    assert _numbers(frames.images) == [0, 3, 6, 9]
    np.testing.assert_allclose(frames.timestamps, [0, 0.12, 0.24, 0.36], atol=1e-3)


def test_keyframe_selection(make_video) -> None:
    frames = read_video(make_video(n=10), FrameSelection(num_keyframes=4))
    np.testing.assert_array_equal(frames.indices, [0, 3, 6, 9])
    assert _numbers(frames.images) == [0, 3, 6, 9]
    more = read_video(make_video("b.mp4", n=3), FrameSelection(num_keyframes=8))
    np.testing.assert_array_equal(more.indices, [0, 1, 2])


def test_time_range_selection(make_video) -> None:
    path = make_video(n=10)  # 25 fps: frame k at k * 0.04 s
    frames = read_video(path, FrameSelection(start_s=0.1, end_s=0.2))
    np.testing.assert_array_equal(frames.indices, [3, 4, 5])
    assert _numbers(frames.images) == [3, 4, 5]
    keyed = read_video(path, FrameSelection(start_s=0.08, num_keyframes=3))
    np.testing.assert_array_equal(keyed.indices, [2, 6, 9])


def test_time_range_outside_video(make_video) -> None:
    with pytest.raises(EmptyVideoError, match=r"clip\.mp4.*no frame in the selected time range"):
        read_video(make_video(n=5), FrameSelection(start_s=10.0))


def test_max_side_downscales(make_video) -> None:
    frames = read_video(make_video(n=2, width=64, height=48), max_side=32)
    assert frames.images.shape == (2, 24, 32, 3)


def test_not_a_video(tmp_path: Path) -> None:
    path = tmp_path / "notes.mp4"
    path.write_text("these are not frames\n" * 50)
    with pytest.raises(NotAVideoError, match=r"notes\.mp4: not a video"):
        read_video(path)
    with pytest.raises(NotAVideoError):
        read_frames(path)


def test_audio_only_file_is_not_a_video(tmp_path: Path) -> None:
    path = tmp_path / "sound.wav"
    container = av.open(str(path), "w")
    stream = container.add_stream("pcm_s16le", rate=8000)
    samples = np.zeros((1, 800), dtype=np.int16)
    frame = av.AudioFrame.from_ndarray(samples, format="s16", layout="mono")
    frame.sample_rate = 8000
    for packet in stream.encode(frame):
        container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()
    with pytest.raises(NotAVideoError, match="no video stream"):
        read_video(path)


@pytest.mark.parametrize("name", ["empty.avi", "empty.mkv"])
def test_video_without_frames(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    container = av.open(str(path), "w")
    stream = container.add_stream("libx264", rate=25)
    stream.width, stream.height, stream.pix_fmt = 32, 32, "yuv420p"
    container.start_encoding()  # header only, no frame
    container.close()
    assert path.stat().st_size > 0
    with pytest.raises(EmptyVideoError, match=rf"{name}: .*(no frame|before any frame)"):
        read_video(path)


def test_zero_byte_file(tmp_path: Path) -> None:
    path = tmp_path / "zero.mp4"
    path.write_bytes(b"")
    with pytest.raises(EmptyVideoError, match=r"zero\.mp4: the file is empty"):
        read_frames(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputNotFoundError, match=r"nothing\.mp4"):
        read_frames(tmp_path / "nothing.mp4")
    with pytest.raises(FileNotFoundError):  # also a FileNotFoundError for generic handlers
        read_video(tmp_path / "nothing.mp4")


def _corrupt_packet(path: Path, which: int) -> Path:
    """Overwrite the payload of the packet of frame ``which`` (presentation order) with random
    bytes."""
    container = av.open(str(path))
    packets = sorted((p.pts, p.pos, p.size) for p in container.demux(video=0) if p.size)
    container.close()
    _, pos, size = packets[which]
    data = bytearray(path.read_bytes())
    noise = np.random.default_rng(1).integers(0, 256, size - 4, dtype=np.uint8)
    data[pos + 4 : pos + size] = noise.tobytes()
    bad = path.with_name("bad_" + path.name)
    bad.write_bytes(bytes(data))
    return bad


def test_corrupt_frame_is_skipped_with_warning(tmp_path: Path) -> None:
    path = write_video(tmp_path / "c.mp4", n=12)
    bad = _corrupt_packet(path, 5)
    with pytest.warns(CorruptFrameWarning, match=r"bad_c\.mp4: skipped 1 frame.*\[5\]") as rec:
        frames = read_video(bad)
    assert len(rec) == 1
    assert 5 not in frames.indices.tolist()
    assert len(frames) == 11
    # every frame that came back carries its true index
    assert _numbers(frames.images[:5]) == [0, 1, 2, 3, 4]


def test_corrupt_frame_raises_on_request(tmp_path: Path) -> None:
    bad = _corrupt_packet(write_video(tmp_path / "c.mp4", n=12), 5)
    with pytest.raises(CorruptFrameError, match=r"bad_c\.mp4: 1 frame\(s\) could not be decoded")\
            as info:
        read_video(bad, on_corrupt="raise")
    assert info.value.frames == [5]


def test_corrupt_frame_outside_selection_is_ignored(tmp_path: Path) -> None:
    bad = _corrupt_packet(write_video(tmp_path / "c.mp4", n=12), 5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frames = read_video(bad, FrameSelection(end_s=0.1))  # frames 0, 1, 2
    np.testing.assert_array_equal(frames.indices, [0, 1, 2])


def test_truncated_video(tmp_path: Path) -> None:
    path = write_video(tmp_path / "t.mp4", n=10)
    data = path.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])  # the index (moov box) at the end is lost
    with pytest.raises(TruncatedVideoError, match=r"cut\.mp4: .*cut short.*copy it again"):
        read_video(cut)


def test_truncated_faststart_video_is_refused_not_read_in_part(tmp_path: Path) -> None:
    # the index comes first (a streaming-friendly mp4): the header announces every frame, the
    # data of most is gone; reading the rest would make an avatar from part of the turn
    path = write_video(tmp_path / "f.mp4", n=24, faststart=True)
    data = path.read_bytes()
    start = data.find(b"mdat")
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: start + (len(data) - start) * 4 // 10])
    with pytest.raises(TruncatedVideoError, match=r"'mdat' box .* 40 % of it is there"):
        read_video(cut)
    assert read_video(path).images.shape[0] == 24  # the whole file is fine


def test_truncated_avi(tmp_path: Path) -> None:
    path = write_video(tmp_path / "a.avi", n=30, codec="mpeg4")
    data = path.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(TruncatedVideoError, match=r"declares .* but only 50 % of it"):
        read_video(cut)


def test_a_header_announcing_more_frames_than_the_file_holds(tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch,
                                                             ) -> None:  # fmt: skip
    # (a container whose header counts frames its data no longer has, e.g. a cut AVI or MKV
    # that FFmpeg still opens); the header's count is PyAV's ``stream.frames``
    from monoavatar.io import video

    path = write_video(tmp_path / "h.mp4", n=20)
    monkeypatch.setattr(video, "_announced_frames", lambda stream: 40)
    with pytest.raises(TruncatedVideoError, match=r"announces 40 frames but only 20 .* \(50 %\)"):
        read_video(path)
    monkeypatch.setattr(video, "_announced_frames", lambda stream: 21)  # 95 %: usable
    assert read_video(path).images.shape[0] == 20


def test_bad_arguments(make_video) -> None:
    with pytest.raises(ValueError, match="on_corrupt"):
        read_video(make_video(n=2), on_corrupt="ignore")  # type: ignore[arg-type]
    with pytest.raises(NotAVideoError, match="not a file"):
        read_video(make_video(n=2).parent)


def test_large_frames_are_downscaled_on_reading(tmp_path: Path) -> None:
    path = write_video(tmp_path / "big.mp4", n=3, width=320, height=240)
    frames = read_video(path, max_side=160)
    assert frames.images.shape[1:3] == (120, 160)
    assert frames.source_size == (320, 240) and frames.scale == pytest.approx(0.5)
    # the downscaled frame is the full one resized (area interpolation), not a crop
    full = read_video(path)
    assert full.source_size is None and full.scale == 1.0
    small = full.images[0].reshape(120, 2, 160, 2, 3).mean(axis=(1, 3))
    assert np.abs(frames.images[0].astype(float) - small).mean() < 2.0
    assert read_video(path, max_side=400).source_size is None  # already small enough
    assert frames.subset([0, 2]).source_size == (320, 240)
