"""The extended path-traced bench's tooling: stations per split, per-kind figures."""

from types import SimpleNamespace

import numpy as np
import pytest

from allo_mrad_ros.synth.config import preset
from benchmarks.stations import OUTPOSTS, PT_SPLITS, generate_bench, write_outposts
from benchmarks.stations_bench import (
    BenchFrame,
    NamedSetting,
    SettingResult,
    format_kinds,
    frame_found,
    frame_kind,
    per_kind,
    per_station_decisions,
)


def test_validation_and_test_share_no_station(tmp_path):
    assert not set(PT_SPLITS["val"]) & set(PT_SPLITS["test"])
    assert "station" in PT_SPLITS["val"]
    outposts = {s for split in PT_SPLITS.values() for s in split} - {"station"}
    assert outposts <= set(OUTPOSTS)
    # Each split has one station with its materials in maps and one with flat factors.
    for split in PT_SPLITS.values():
        textured = [OUTPOSTS[s][1] if s in OUTPOSTS else False for s in split]
        assert sorted(textured) == [False, True]
    written = write_outposts(tmp_path)
    assert sorted(p.name for p in written) == sorted(f"{n}.glb" for n in OUTPOSTS)
    assert preset("bench-pt").hard_kinds


def _frame(kind: str, station: str, positive: bool, shape=(8, 8)) -> BenchFrame:
    truth = np.zeros(shape, np.uint8)
    if positive:
        truth[2:4, 2:4] = 2
    empty = np.zeros((*shape, 3), np.uint8)
    return BenchFrame(station, "x" if positive else "", empty, truth, empty, kind)


def _result(frames, scores, found) -> SettingResult:
    result = SettingResult(NamedSetting("s", "MRAD", None))
    result.scores = scores
    result.found = found
    return result


def test_per_kind_scores_each_kind_against_every_negative():
    rng = np.random.default_rng(0)
    frames = [
        _frame("", "a", False),
        _frame("", "b", False),
        _frame("thin_cable", "a", True),
        _frame("small", "b", True),
        _frame("invisible", "b", True),
    ]
    scores = [rng.uniform(0.0, 0.5, (8, 8)) for _ in frames]
    scores[2][frames[2].truth == 2] = 0.9  # above every negative: perfect
    scores[3][frames[3].truth == 2] = 0.0  # below every negative
    scores[4][frames[4].truth == 2] = 0.9  # perfect too, but its own kind
    result = _result(frames, scores, [False, True, True, False, True])
    kinds = per_kind(frames, result)
    assert set(kinds) == {"thin_cable", "small", "invisible"}
    assert kinds["thin_cable"] == {"frames": 1, "p_ap": 100.0, "recall": 100.0, "found": 1}
    assert kinds["small"]["recall"] == 0.0 and kinds["small"]["found"] == 0
    # Every negative scores at least as high: precision at full recall is 4 / all pixels.
    negatives = sum(int(np.count_nonzero(f.truth != 2)) for f in frames)
    assert kinds["small"]["p_ap"] == pytest.approx(100 * 4 / (negatives + 4), abs=0.1)
    # The invisible object's perfect pixels do not lift the small kind's figure.
    assert kinds["invisible"]["p_ap"] == 100.0
    decisions = per_station_decisions(frames, result)
    assert decisions["a"] == {"flagged": [0, 1], "found": [1, 1]}
    assert decisions["b"] == {"flagged": [1, 1], "found": [1, 2]}
    assert "thin_cable" in format_kinds("s", kinds)


def test_a_frame_is_found_only_when_its_mask_touches_the_object():
    truth = np.zeros((6, 6), np.uint8)
    truth[1:3, 1:3] = 2
    elsewhere = np.zeros((6, 6), bool)
    elsewhere[5, 5] = True
    on = np.zeros((6, 6), bool)
    on[2, 2] = True
    assert not frame_found(SimpleNamespace(anomalous=True, mask=elsewhere), truth)
    assert frame_found(SimpleNamespace(anomalous=True, mask=on), truth)
    assert not frame_found(SimpleNamespace(anomalous=False, mask=on), truth)
    assert frame_found(SimpleNamespace(anomalous=True, mask=elsewhere), np.zeros((6, 6)))


def test_frame_kind_reads_the_columns():
    def frame(anomaly, **extra):
        return SimpleNamespace(anomaly=anomaly, extra=extra)

    assert frame_kind(frame("")) == ""
    assert frame_kind(frame("drill")) == "other"
    assert frame_kind(frame("thin_cable", kind="thin_cable", visible="1")) == "thin_cable"
    assert frame_kind(frame("black_foil", kind="dark_over_space", visible="0")) == "invisible"


def test_each_station_of_the_pt_bench_gets_its_own_seed(tmp_path, monkeypatch):
    import allo_mrad_ros.synth.generator as generator

    seeds = {}

    def fake_generate(config, folder, seed, **options):
        seeds[(folder.parent.name, folder.name)] = (config.name, seed)
        folder.mkdir(parents=True, exist_ok=True)

    monkeypatch.setattr(generator, "generate", fake_generate)
    write_outposts(tmp_path / "models")
    generate_bench(tmp_path / "models", tmp_path / "bench", PT_SPLITS, "bench-pt", True)
    assert seeds == {
        ("val", "station"): ("bench-pt", 1),
        ("val", "outpost_hub"): ("bench-pt", 3),
        ("test", "outpost_spine"): ("bench-pt", 0),
        ("test", "outpost_ring"): ("bench-pt", 2),
    }
