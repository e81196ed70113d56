"""The benchmark suite: fixed and versioned, varied, small in its quick form; scene caching."""

import json

import pytest

from monoavatar.bench.suite import (
    CATEGORIES,
    MODES,
    SUITE_VERSION,
    BenchSubject,
    SuiteError,
    ensure_scene,
    get_suite,
    scene_is_valid,
)
from monoavatar.synth.options import CLOTHING
from monoavatar.synth.scene import SynthConfig

# The suite's definition, pinned: changing any of it changes the figures and needs a new
# SUITE_VERSION (and this list updated with it).
PINNED_SUBJECTS = [
    ("minimal-s3", "minimal", 3, "minimal"),
    ("minimal-s7", "minimal", 7, "minimal"),
    ("minimal-s19", "minimal", 19, "minimal"),
    ("minimal-s37", "minimal", 37, "minimal"),
    ("clothed-tight-s24", "clothed", 24, "tight"),
    ("clothed-tshirt-shorts-s14", "clothed", 14, "tshirt-shorts"),
    ("clothed-longsleeve-trousers-s21", "clothed", 21, "longsleeve-trousers"),
    ("clothed-loose-s27", "clothed", 27, "loose"),
    ("clothed-skirt-s35", "clothed", 35, "skirt"),
]


def test_full_suite_is_pinned_and_versioned():
    suite = get_suite()
    assert suite.version == SUITE_VERSION == 2  # v1's subjects, synth format 2
    assert [(s.name, s.category, s.seed, s.clothing) for s in suite.subjects] == PINNED_SUBJECTS
    for s in suite.subjects:
        assert (s.frames, s.width, s.height, s.keyframes, s.texture_size) == (
            120, 540, 540, 30, 1024)  # fmt: skip


def test_full_suite_is_deterministic():
    a, b = get_suite(), get_suite()
    assert a == b
    assert [s.synth_settings() for s in a.subjects] == [s.synth_settings() for s in b.subjects]
    assert json.dumps(a.to_dict()) == json.dumps(b.to_dict())


def test_full_suite_covers_categories_and_garments():
    subjects = get_suite().subjects
    assert len(subjects) >= 9
    assert {s.category for s in subjects} == set(CATEGORIES)
    assert {s.clothing for s in subjects if s.category == "clothed"} == set(CLOTHING) - {"minimal"}
    assert all(s.clothing == "minimal" for s in subjects if s.category == "minimal")
    assert len({s.name for s in subjects}) == len(subjects)
    assert len({s.seed for s in subjects}) == len(subjects)


def test_settings_are_valid_synth_configs():
    for s in get_suite().subjects + get_suite(quick=True).subjects:
        config = SynthConfig(**s.synth_settings())
        config.validate()
        assert config.kind == "turnaround"
        assert config.seed == s.seed and config.clothing == s.clothing


def test_quick_suite_is_small():
    quick = get_suite(quick=True)
    assert quick.name == "quick" and quick.version == SUITE_VERSION
    assert len(quick.subjects) == 1
    (s,) = quick.subjects
    assert s.frames <= 16 and s.width <= 256 and s.height <= 256
    assert s.texture_size <= 256 and 2 <= s.keyframes < s.frames


def test_modes_are_estimated_shape_only_and_ground_truth_poses():
    assert [m.name for m in MODES] == ["estimated", "shape-only", "gt-poses"]
    assert (MODES[0].perception, MODES[0].poses, MODES[0].offsets) == ("mediapipe", "fit", True)
    assert (MODES[1].perception, MODES[1].poses, MODES[1].offsets) == ("mediapipe", "fit", False)
    assert MODES[2].poses == "ground-truth" and MODES[2].offsets


def test_select_keeps_suite_order_and_rejects_unknown_names():
    suite = get_suite()
    picked = suite.select(["clothed-skirt-s35", "minimal-s7"])
    assert [s.name for s in picked.subjects] == ["minimal-s7", "clothed-skirt-s35"]
    assert suite.select(None) is suite
    with pytest.raises(SuiteError, match="minimal-s3"):
        suite.select(["nobody"])
    with pytest.raises(SuiteError, match="no subject"):
        suite.select([])


def test_subject_checks_its_settings():
    with pytest.raises(SuiteError, match="held out"):
        BenchSubject("x", "minimal", 1, "minimal", frames=10, keyframes=10)
    with pytest.raises(SuiteError, match="category"):
        BenchSubject("x", "naked", 1, "minimal")
    with pytest.raises(SuiteError, match="clothing"):
        BenchSubject("x", "clothed", 1, "cape")


def test_scene_is_reused_when_valid_and_replaced_when_not(tiny_scene, anny_local, tmp_path):
    subject, scenes, folder = tiny_scene
    assert scene_is_valid(folder, subject)
    stamp = (folder / "scene.json").stat().st_mtime_ns
    assert ensure_scene(subject, scenes, body=anny_local) == folder
    assert (folder / "scene.json").stat().st_mtime_ns == stamp  # reused, not regenerated

    other = BenchSubject(subject.name, subject.category, subject.seed + 1, subject.clothing,
                         frames=subject.frames, width=subject.width, height=subject.height,
                         keyframes=subject.keyframes,
                         texture_size=subject.texture_size)  # fmt: skip
    assert not scene_is_valid(folder, other)  # another seed: not this scene

    # a scene made before the capture profiles (no "capture" recorded) was a studio take
    import shutil

    older = tmp_path / "older"
    shutil.copytree(folder, older)
    info = json.loads((older / "scene.json").read_text())
    assert info["config"].pop("capture") == "studio"
    (older / "scene.json").write_text(json.dumps(info))
    assert scene_is_valid(older, subject)
    info["config"]["capture"] = "phone"
    (older / "scene.json").write_text(json.dumps(info))
    assert not scene_is_valid(older, subject)

    # a stale copy (other settings) in the cache folder is regenerated
    stale = tmp_path / subject.name
    shutil.copytree(folder, stale)
    info = json.loads((stale / "scene.json").read_text())
    info["config"]["seed"] = 999
    (stale / "scene.json").write_text(json.dumps(info))
    assert not scene_is_valid(stale, subject)
    assert ensure_scene(subject, tmp_path, body=anny_local) == stale
    assert scene_is_valid(stale, subject)

    # so is one that an older generator made with the same settings
    info = json.loads((stale / "scene.json").read_text())
    info["format"] = "monoavatar-synth-1"
    (stale / "scene.json").write_text(json.dumps(info))
    assert not scene_is_valid(stale, subject)


def test_a_foreign_folder_is_not_deleted(tmp_path):
    subject = get_suite(quick=True).subjects[0]
    foreign = tmp_path / subject.name
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(SuiteError, match="not a scene folder"):
        ensure_scene(subject, tmp_path)
    assert (foreign / "notes.txt").read_text() == "mine"


def test_suite_v2_has_a_dev_and_a_sealed_test_split_of_phone_takes():
    from monoavatar.bench.suite import SPLITS, SUITE_V2_VERSION, V2_SUBJECTS

    dev, test = (get_suite(suite="v2", split=s) for s in SPLITS)
    assert (dev.name, test.name) == ("v2-dev", "v2-test")
    assert dev.version == test.version == SUITE_V2_VERSION
    assert [s.seed for s in dev.subjects] == [5001, 5002, 5003, 5004]
    assert [s.seed for s in test.subjects] == list(range(6001, 6009))
    v1_seeds = {s.seed for s in get_suite().subjects}
    seeds = [s.seed for s in dev.subjects + test.subjects]
    assert len(set(seeds)) == len(seeds) and not v1_seeds & set(seeds)
    for s in dev.subjects + test.subjects:
        assert (s.capture, s.variety, s.from_video) == ("phone", "wide", True)
        assert s.synth_settings()["capture"] == "phone"
        assert s.name.startswith(f"v2{'dev' if s in V2_SUBJECTS['dev'] else 'test'}-")
    assert {s.category for s in test.subjects} == {"minimal", "clothed"}
    with pytest.raises(SuiteError, match="unknown split"):
        get_suite(suite="v2", split="train")
    with pytest.raises(SuiteError, match="unknown suite"):
        get_suite(suite="v3")
