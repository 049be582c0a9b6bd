"""Station models for the multi-station path-traced bench (``make bench-stations``).

Public spacecraft models (NASA's 3D Resources, glTF binary) come as their authors exported
them: arbitrary units (centimetres, inches, a unit cube), Draco-compressed geometry, nodes
with scales. :func:`prepare_station` turns one into what the generator and the renderer
read: decoded geometry, the model's own materials and textures kept, centred on its bounding
box and scaled so that its longest side has the real craft's length in metres.

The models are not part of the package or of git: put the ``.glb`` files named in
:data:`STATIONS` into a folder (``STATIONS_SRC``, default ``data/stations``) and run
``make bench-stations``. The ISS model is held out for evaluation: it is in no bench.

The extended path-traced bench (``make bench-pt``) uses no external model: the package's
station and three procedural outposts of other layouts and materials
(:mod:`allo_mrad_ros.render.outpost_model`; two of them with their materials in texture
maps, as a CAD export writes them), :data:`PT_SPLITS`, generated with the ``bench-pt``
preset.

Usage::

    python -m benchmarks.stations prepare data/stations --out data/stations_prepared
    python -m benchmarks.stations generate data/stations_prepared \\
        --out data/bench_stations
    python -m benchmarks.stations outposts data/stations_pt
    python -m benchmarks.stations generate data/stations_pt --bench pt --out data/bench_pt
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from allo_mrad_ros.errors import InvalidInput

__all__ = [
    "BENCH_SPLITS",
    "OUTPOSTS",
    "PT_SPLITS",
    "STATIONS",
    "StationError",
    "StationModel",
    "generate_bench",
    "prepare_station",
]


class StationError(InvalidInput):
    """A station model cannot be prepared."""


@dataclass(frozen=True)
class StationModel:
    """One public model of the bench.

    Attributes
    ----------
    name : str
        Short name (also the prepared file's stem).
    source : str
        File name in NASA-3D-Resources' ``3D Models`` tree as redistributed (``.glb``).
    length_m : float
        Longest side of the real craft, metres.
    """

    name: str
    source: str
    length_m: float


STATIONS: dict[str, StationModel] = {
    model.name: model
    for model in (
        StationModel("skylab", "skylab.glb", 36.1),
        StationModel("tdrs", "tdrs.glb", 17.4),
        StationModel("hubble", "hubble_space_telescope.glb", 13.2),
        StationModel("apollo_soyuz", "apollo_soyuz.glb", 20.0),
        StationModel("mir", "mir.glb", 31.0),
    )
}
"""Real public models of the bench (``station`` is the package's own procedural mesh)."""

BENCH_SPLITS: dict[str, tuple[str, ...]] = {
    "val": ("station", "skylab", "tdrs"),
    "test": ("hubble", "apollo_soyuz", "mir"),
}
"""Stations per split: defaults are chosen on ``val``; ``test`` shares no model with it."""

OUTPOSTS: dict[str, tuple[str, bool]] = {
    "outpost_hub": ("hub", True),
    "outpost_spine": ("spine", True),
    "outpost_ring": ("ring", False),
}
"""Procedural outposts of the extended path-traced bench: name to (layout, textured)."""

PT_SPLITS: dict[str, tuple[str, ...]] = {
    "val": ("station", "outpost_hub"),
    "test": ("outpost_spine", "outpost_ring"),
}
"""Stations per split of the extended path-traced bench (``make bench-pt``): each split has
one station with its materials in texture maps and one with flat factors; none is shared."""
BENCHES = {"stations": ("bench-stations", BENCH_SPLITS), "pt": ("bench-pt", PT_SPLITS)}
"""Bench name to (generator preset, stations per split)."""
STATION_SEEDS = {"stations": False, "pt": True}
"""Whether a bench gives each station of a split its own seed (its own objects and draws:
per-kind figures then count distinct objects) or one seed per split."""


def write_outposts(out: Path) -> list[Path]:
    """Write the outposts of :data:`OUTPOSTS` into ``out`` (each ``<name>.glb``)."""
    return [write_outpost(out / f"{name}.glb") for name in OUTPOSTS]


def write_outpost(path: Path) -> Path:
    """Write the outpost that ``path``'s stem names (one of :data:`OUTPOSTS`) to ``path``."""
    from allo_mrad_ros.render.outpost_model import build_outpost

    layout, textured = OUTPOSTS[path.stem]
    path.parent.mkdir(parents=True, exist_ok=True)
    scene = build_outpost(layout, textured)
    path.write_bytes(scene.export(file_type="glb", include_normals=True))
    return path


def prepare_station(source: Path, destination: Path, length_m: float) -> dict[str, float]:
    """Decode, centre and scale one glTF model, keeping its materials.

    Parameters
    ----------
    source : Path
        A ``.glb`` file (Draco-compressed geometry needs the ``DracoPy`` package).
    destination : Path
        The ``.glb`` to write.
    length_m : float
        Length of the longest bounding-box side after scaling, > 0.

    Returns
    -------
    dict
        ``faces``, ``scale`` and the written extents.

    Raises
    ------
    StationError
        When the file cannot be read, holds no triangles, or its geometry did not decode.
    """
    if not length_m > 0:
        raise StationError(f"length_m must be positive, got {length_m!r}")
    try:
        scene = trimesh.load(source, force="scene")
    except Exception as error:
        raise StationError(f"{source}: cannot read the model ({error})") from None
    meshes = [g for g in scene.geometry.values() if isinstance(g, trimesh.Trimesh)]
    faces = sum(len(mesh.faces) for mesh in meshes)
    if faces == 0:
        raise StationError(f"{source}: the model holds no triangles")
    extents = np.asarray(scene.extents, dtype=float)
    if not np.all(np.isfinite(extents)) or extents.max() <= 0:
        raise StationError(
            f"{source}: the geometry did not decode (all vertices at one point); "
            "Draco-compressed models need the DracoPy package"
        )
    scale = length_m / float(extents.max())
    centre = np.asarray(scene.bounds, dtype=float).mean(axis=0)
    transform = np.eye(4)
    transform[:3, :3] *= scale
    transform[:3, 3] = -scale * centre
    scene.apply_transform(transform)
    destination.parent.mkdir(parents=True, exist_ok=True)
    scene.export(destination, file_type="glb")
    return {
        "faces": float(faces),
        "scale": scale,
        **dict(zip("xyz", scene.extents.tolist(), strict=True)),
    }


def generate_bench(
    prepared: Path,
    out: Path,
    splits: dict[str, tuple[str, ...]] = BENCH_SPLITS,
    preset_name: str = "bench-stations",
    station_seeds: bool = False,
) -> list[Path]:
    """Generate each split's station sequences (``preset_name``) not yet there.

    The validation split uses seed 1, the test split seed 0, so no two share a frame plan;
    with ``station_seeds`` the i-th station of a split adds ``2 i`` (val 1, 3, ...; test 0,
    2, ...), so no two stations share their objects either.
    The package's own station is ``station``. Needs the optional ``bpy``. A station folder
    without ``frames.csv`` is regenerated only when it holds nothing but a sequence's files.

    Returns
    -------
    list of Path
        The sequences generated now.
    """
    from allo_mrad_ros.resources import share_path
    from allo_mrad_ros.synth.config import preset
    from allo_mrad_ros.synth.generator import generate
    from allo_mrad_ros.targets import SEQUENCE, TargetError, check_target

    made = []
    for split, stations in splits.items():
        for index, station in enumerate(stations):
            folder = out / split / station
            if (folder / "frames.csv").is_file():
                continue
            mesh = (
                share_path("meshes", "station.glb")
                if station == "station"
                else prepared / f"{station}.glb"
            )
            if not mesh.is_file():
                raise StationError(f"{mesh}: prepared model missing (run the prepare step)")
            try:
                # A partial sequence of ours is replaced; anything else there is refused.
                check_target(folder, SEQUENCE, overwrite=True, inputs=(mesh,))
            except TargetError as error:
                raise StationError(str(error)) from None
            seed = (1 if split == "val" else 0) + (2 * index if station_seeds else 0)
            start = time.perf_counter()
            generate(preset(preset_name), folder, seed, mesh=mesh, overwrite=True, progress=False)
            print(f"generated {folder} in {time.perf_counter() - start:.0f} s", flush=True)
            made.append(folder)
    return made


def main(argv: list[str] | None = None) -> int:
    """``prepare SOURCE --out PREPARED``, ``outposts FOLDER`` or ``generate PREPARED --out
    BENCH [--bench pt]``."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("step", choices=("prepare", "outposts", "generate"))
    parser.add_argument("source", type=Path, help="models' .glb folder, or prepared models")
    parser.add_argument("--out", type=Path, help="output folder (prepare, generate)")
    parser.add_argument("--bench", choices=tuple(BENCHES), default="stations")
    args = parser.parse_args(argv)
    if args.step == "outposts":
        for path in write_outposts(args.source):
            print(f"wrote {path}")
        return 0
    if args.out is None:
        parser.error(f"{args.step} needs --out")
    if args.step == "generate":
        preset_name, splits = BENCHES[args.bench]
        try:
            generate_bench(args.source, args.out, splits, preset_name, STATION_SEEDS[args.bench])
        except StationError as error:
            print(f"stations: {error}", file=sys.stderr)
            return 2
        return 0
    missing = [m.source for m in STATIONS.values() if not (args.source / m.source).is_file()]
    if missing:
        print(
            f"stations: missing in {args.source}: {', '.join(missing)} "
            "(NASA-3D-Resources, '3D Models' folder)",
            file=sys.stderr,
        )
        return 2
    for model in STATIONS.values():
        try:
            facts = prepare_station(
                args.source / model.source, args.out / f"{model.name}.glb", model.length_m
            )
        except StationError as error:
            print(f"stations: {error}", file=sys.stderr)
            return 2
        extents = " x ".join(f"{facts[a]:.1f}" for a in "xyz")
        print(f"{model.name}: {int(facts['faces'])} faces, {extents} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
