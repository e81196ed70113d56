"""``monoavatar batch``: inputs and names, failure isolation, the summary, re-runs, and a real
local Ray cluster."""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path

import pytest

from monoavatar.batch import (
    BatchError,
    BatchSettings,
    expand_inputs,
    is_complete,
    plan_items,
    runner,
)
from monoavatar.batch.runner import current_stage, error_line, run_batch
from monoavatar.cli import main


def test_list_files_are_expanded_relative_to_themselves(tmp_path: Path) -> None:
    (tmp_path / "lists").mkdir()
    listing = tmp_path / "lists" / "captures.txt"
    listing.write_text("# monday\nclip1.mp4\n\n  sub/frames  \n/abs/clip2.mov\n")
    paths = expand_inputs([listing, tmp_path / "other.mp4"])
    assert paths == [tmp_path / "lists" / "clip1.mp4", tmp_path / "lists" / "sub" / "frames",
                     Path("/abs/clip2.mov"), tmp_path / "other.mp4"]  # fmt: skip
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing\n")
    with pytest.raises(BatchError, match="no inputs"):
        expand_inputs([empty])


def test_names_are_unique_and_folders_complete_only_with_their_files(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "frames").mkdir()
    inputs = [tmp_path / "a" / "clip.mp4", tmp_path / "b" / "clip.mov",
              tmp_path / "a" / "frames", tmp_path / "clip"]  # fmt: skip
    items = plan_items(inputs, tmp_path / "out")
    assert [i.name for i in items] == ["clip", "clip-2", "frames", "clip-3"]
    assert items[1].output == str(tmp_path / "out" / "clip-2")
    folder = tmp_path / "out" / "clip"
    folder.mkdir(parents=True)
    (folder / "report.json").write_text("{}")
    assert not is_complete(folder, "reconstruct")  # no avatar.glb: not finished
    (folder / "avatar.glb").write_bytes(b"glb")
    assert is_complete(folder, "reconstruct") and not is_complete(folder, "track")


def test_log_readers(tmp_path: Path) -> None:
    log = tmp_path / "log.txt"
    log.write_text("$ monoavatar reconstruct x -o y\nperception:  10%|#\rperception:  60%|######"
                   "\nmonoavatar reconstruct: error: x: no such file or folder\n")  # fmt: skip
    assert error_line(log) == "monoavatar reconstruct: error: x: no such file or folder"
    assert current_stage(log).startswith("monoavatar reconstruct: error")
    log.write_text("perception:  10%|#\rpose fit:  60%|######\r")
    assert current_stage(log) == "pose fit:  60%|######"
    assert error_line(tmp_path / "missing.txt") == "no log"


def test_settings_are_checked() -> None:
    with pytest.raises(BatchError, match="--command"):
        BatchSettings(command="demo").validate()
    with pytest.raises(BatchError, match="--cpus-per-task"):
        BatchSettings(cpus_per_task=0).validate()
    with pytest.raises(BatchError, match="OUT/<name>"):
        BatchSettings(options=("-o", "x")).validate()


def test_without_ray_the_inputs_run_one_after_another(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    said: list[str] = []
    engine = runner._engine(BatchSettings(), said.append)
    assert isinstance(engine, runner._Local)
    assert "Ray is not installed" in said[0]
    with pytest.raises(BatchError, match="--address needs Ray"):
        runner._engine(BatchSettings(address="ray://head:10001"), said.append)


@pytest.mark.slow  # four processes of about 5 s
def test_failures_are_isolated_reported_and_retried(tmp_path: Path) -> None:
    """Two bad photos, one after another without Ray: each fails on its own with the
    command's error, batch.json says so, nothing else is written; a second run retries both."""
    (tmp_path / "broken.jpg").write_bytes(b"not a jpeg")
    listing = tmp_path / "photos.txt"
    listing.write_text("broken.jpg\nmissing.png\n")
    out = tmp_path / "out"
    stream = io.StringIO()
    settings = BatchSettings(command="photo", use_ray=False)
    result = run_batch([listing], out, settings, stream=stream)
    assert [i.status for i in result.items] == ["failed", "failed"]
    assert "not a readable image" in result.items[0].error
    assert "missing.png" in result.items[1].error and result.items[1].returncode == 2
    summary = json.loads((out / "batch.json").read_text())
    assert summary["command"] == "photo" and summary["engine"].startswith("local")
    assert [i["status"] for i in summary["items"]] == ["failed", "failed"]
    for name in ("broken", "missing"):  # only the log: no half-written output
        assert sorted(p.name for p in (out / name).iterdir()) == ["log.txt"]
        assert (out / name / "log.txt").read_text().startswith("$ monoavatar photo ")
    assert "broken" in stream.getvalue() and "failed" in stream.getvalue()
    again = run_batch([listing], out, settings, stream=io.StringIO())
    assert [i.status for i in again.items] == ["failed", "failed"]  # retried, not skipped


def test_batch_command_refuses_unknown_options_before_running(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]
                                                              ) -> None:  # fmt: skip
    out = tmp_path / "out"
    assert main(["batch", str(tmp_path / "a.mp4"), "-o", str(out), "--options",
                 "--no-such-option 3"]) == 2  # fmt: skip
    assert "--options for reconstruct" in capsys.readouterr().err
    assert not out.exists()
    assert main(["batch", str(tmp_path / "a.mp4"), "-o", str(out), "--options", "'open"]) == 2
    assert main(["batch", str(tmp_path / "a.mp4"), "-o", str(out), "--cpus-per-task", "0"]) == 2


@pytest.mark.slow
def test_two_avatars_and_a_corrupt_file_on_a_local_ray_cluster(tmp_path: Path) -> None:
    """A real local Ray cluster (started and stopped by the batch): two small synthetic
    turn-arounds become avatars side by side, the corrupt video fails clearly; a second run
    does nothing for the two and retries the third."""
    pytest.importorskip("ray")  # a dev install has it; the code path is tested above without
    from monoavatar.synth.scene import SynthConfig, generate

    inputs = []
    for seed in (11, 12):
        folder = tmp_path / "in" / f"turn{seed}"
        generate(folder, SynthConfig(kind="turnaround", frames=8, seed=seed, width=192,
                                     height=192, texture_size=64), progress=False)  # fmt: skip
        inputs.append(folder)
    bad = tmp_path / "in" / "broken.mp4"
    bad.write_bytes(b"\x00\x00\x00\x18ftypmp42" + b"garbage" * 100)
    inputs.append(bad)
    out = tmp_path / "out"
    settings = BatchSettings(options=("--fast", "--budget", "1", "--texture-size", "128",
                                      "--quiet"), cpus_per_task=1, progress=False)  # fmt: skip
    first = run_batch(inputs, out, settings)
    assert first.engine.startswith("ray ")
    status = {i.name: i.status for i in first.items}
    assert status == {"turn11": "done", "turn12": "done", "broken": "failed"}
    for name in ("turn11", "turn12"):
        report = json.loads((out / name / "report.json").read_text())
        assert report["settings"]["fast"] is True and (out / name / "avatar.glb").is_file()
    broken = next(i for i in first.items if i.name == "broken")
    assert broken.returncode == 2 and "broken.mp4" in broken.error
    assert sorted(p.name for p in (out / "broken").iterdir()) == ["log.txt"]
    summary = json.loads((out / "batch.json").read_text())
    assert sorted(i["status"] for i in summary["items"]) == ["done", "done", "failed"]
    stamp = (out / "turn11" / "avatar.glb").stat().st_mtime_ns
    second = run_batch(inputs, out, settings)
    status = {i.name: i.status for i in second.items}
    assert status == {"turn11": "skipped", "turn12": "skipped", "broken": "failed"}
    assert (out / "turn11" / "avatar.glb").stat().st_mtime_ns == stamp


@pytest.mark.slow  # a reconstruction started and stopped: about 20 s
def test_sigterm_stops_a_batch_started_with_sigint_ignored(tmp_path: Path) -> None:
    """A batch run as a script's background job (SIGINT ignored) and stopped with ``kill``
    (SIGTERM) interrupts its running command, which removes its staged files and says so,
    instead of leaving it to run on, or to be killed half-written after the grace period."""
    import signal
    import subprocess
    import time

    from monoavatar.synth.scene import SynthConfig, generate

    scene = tmp_path / "in" / "turn"
    generate(scene, SynthConfig(kind="turnaround", frames=8, seed=11, width=192, height=192,
                                texture_size=64), progress=False)  # fmt: skip
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "monoavatar.cli", "batch", str(scene), "-o", str(out),
         "--no-ray", "--quiet"],
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    log = out / "turn" / "log.txt"
    try:
        deadline = time.monotonic() + 120
        # the command is under way: its first texture is being built (three flow rounds, each
        # with a shape and a texture, are still to come)
        while not (log.is_file() and "texture" in log.read_text()):
            assert proc.poll() is None and time.monotonic() < deadline, "no texture started"
            time.sleep(0.2)
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        output, _ = proc.communicate(timeout=25)  # well before the 30-s grace of a kill
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, output
    assert log.read_text().rstrip().endswith("interrupted")  # the command's own clean exit
    assert not [p for p in out.rglob("*") if "staging" in p.name]
    assert not (out / "turn" / "avatar.glb").exists()
