"""The multi-station bench's tooling: model preparation, settings, generator options."""

import numpy as np
import pytest
import trimesh

from allo_mrad_ros.synth.config import SynthConfig, SynthError, preset
from allo_mrad_ros.synth.realism import jpeg_round_trip
from benchmarks.stations import BENCH_SPLITS, StationError, prepare_station
from benchmarks.stations_bench import parse_setting


def test_a_model_in_centimetres_is_centred_and_scaled_to_its_length(tmp_path):
    box = trimesh.creation.box(extents=(400.0, 1000.0, 250.0))  # centimetres
    box.apply_translation((5000.0, -300.0, 80.0))
    source = tmp_path / "craft.glb"
    trimesh.Scene(box).export(source)
    facts = prepare_station(source, tmp_path / "out" / "craft.glb", 10.0)
    prepared = trimesh.load(tmp_path / "out" / "craft.glb", force="scene")
    np.testing.assert_allclose(prepared.extents, (4.0, 10.0, 2.5), atol=1e-4)
    np.testing.assert_allclose(prepared.bounds.mean(axis=0), 0.0, atol=1e-4)
    assert facts["scale"] == pytest.approx(0.01)


def test_a_model_whose_geometry_did_not_decode_is_refused(tmp_path):
    flat = trimesh.Trimesh(np.zeros((3, 3)), [[0, 1, 2]], process=False)
    source = tmp_path / "draco.glb"
    trimesh.Scene(flat).export(source)
    with pytest.raises(StationError, match="did not decode"):
        prepare_station(source, tmp_path / "out.glb", 10.0)


def test_garbage_and_bad_lengths_are_refused(tmp_path):
    source = tmp_path / "garbage.glb"
    source.write_bytes(b"not a model")
    with pytest.raises(StationError, match=r"garbage\.glb"):
        prepare_station(source, tmp_path / "out.glb", 10.0)
    with pytest.raises(StationError, match="length_m"):
        prepare_station(source, tmp_path / "out.glb", 0.0)


def test_validation_and_test_splits_share_no_station_and_hold_out_the_iss():
    val, test = set(BENCH_SPLITS["val"]), set(BENCH_SPLITS["test"])
    assert len(val) >= 3 and len(test) >= 3 and not val & test
    assert not any("iss" in name.lower() for name in val | test)


def test_settings_take_typed_overrides():
    setting = parse_setting("default:transfer_gain=false:transfer_bin=8:glare_level=240")
    assert setting.method == "MRAD"
    params = setting.params
    assert params.transfer_gain is False and params.transfer_bin == 8
    assert params.glare_level == 240.0
    assert parse_setting("no_transfer").params.colour_transfer == "none"
    for bad in ("nonsense", "default:transfer_gain=maybe", "default:no_such=1", "default:x"):
        with pytest.raises(ValueError):
            parse_setting(bad)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"cycles_view_transforms": ("Sepia",)}, "cycles_view_transforms"),
        ({"cycles_view_transforms": "AgX"}, "cycles_view_transforms"),
        ({"cycles_exposure_ev": (1.0, -1.0)}, "cycles_exposure_ev"),
        ({"cycles_exposure_ev": (-1.0, 12.0)}, "cycles_exposure_ev"),
        ({"jpeg_quality": 101}, "jpeg_quality"),
        ({"jpeg_quality": True}, "jpeg_quality"),
    ],
)
def test_generator_development_options_are_validated(changes, message):
    with pytest.raises(SynthError, match=message):
        preset("bench-stations").with_overrides(**changes)


def test_the_bench_preset_develops_each_frame_its_own_way():
    config = preset("bench-stations")
    assert isinstance(config, SynthConfig) and config.query_renderer == "cycles"
    assert set(config.cycles_view_transforms) >= {"AgX", "Filmic", "Standard"}
    low, high = config.cycles_exposure_ev
    assert low < 0 < high and 0 < config.jpeg_quality < 100


def test_jpeg_round_trip_keeps_the_image_and_adds_compression_error():
    rng = np.random.default_rng(0)
    image = cv2_friendly(rng)
    out = jpeg_round_trip(image, 50)
    assert out.shape == image.shape and out.dtype == np.uint8
    error = np.abs(out.astype(int) - image.astype(int))
    assert 0 < error.mean() < 20
    # Channel order survives the codec (OpenCV's BGR is undone).
    red = np.zeros((64, 64, 3), np.uint8)
    red[..., 0] = 200
    assert jpeg_round_trip(red, 95)[..., 0].mean() > 150 > jpeg_round_trip(red, 95)[..., 2].mean()


def cv2_friendly(rng: np.random.Generator) -> np.ndarray:
    # Smooth blocks plus noise: an image JPEG changes but does not destroy.
    blocks = rng.integers(0, 256, (8, 8, 3)).astype(np.uint8)
    image = np.kron(blocks, np.ones((16, 16, 1), np.uint8))
    return np.clip(image.astype(int) + rng.integers(-5, 6, image.shape), 0, 255).astype(np.uint8)


def test_the_bench_names_a_missing_station_sequence_in_one_line(tmp_path, capsys):
    from benchmarks.stations_bench import main

    assert main([str(tmp_path), "--split", "val"]) == 2
    assert "station sequence missing" in capsys.readouterr().err


def test_generation_refuses_a_station_folder_holding_other_files(tmp_path):
    from benchmarks.stations import generate_bench

    folder = tmp_path / "bench" / "val" / "station"
    folder.mkdir(parents=True)
    (folder / "notes.txt").write_text("mine")
    with pytest.raises(StationError, match="station"):
        generate_bench(tmp_path, tmp_path / "bench", {"val": ("station",)})
    assert (folder / "notes.txt").read_text() == "mine"
