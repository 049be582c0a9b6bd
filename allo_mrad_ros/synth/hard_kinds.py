"""The hard object kinds of the path-traced bench: placement rules, measures and labels.

Each anomalous frame of a sequence with ``hard_kinds`` gets a ``kind`` column:

========================  ==============================================================
``thin_cable``            a ``thin_cable`` whose silhouette is 1-4 px wide
``dark_over_surface``     a dark type (:data:`~.objects.DARK_TYPES`) seen mostly against
                          the station
``dark_over_space``       a dark type seen mostly against space
``small``                 any object of at most :data:`SMALL_MAX_PX` pixels
``station_coloured``      a ``station_patch`` (painted with the station's own dominant
                          material) seen mostly against the station
``other``                 everything else
========================  ==============================================================

and a ``visible_fraction`` column: the share of the object's pixels that differ from what
is behind them in the clean path-traced query, where "behind" is space (a pixel of the
object in front of space is invisible when it is as dark as space there). An object with
less than :data:`VISIBLE_SHARE` of its pixels visible is marked ``visible = 0``: the truth
mask still holds it, and per-kind figures report it apart.
"""

from __future__ import annotations

import math
from os import PathLike

import cv2
import numpy as np
import trimesh
from trimesh.visual.material import PBRMaterial

from allo_mrad_ros.render import LABEL_ANOMALY, LABEL_SPACE, LABEL_STATION
from allo_mrad_ros.synth.objects import DARK_TYPES

THIN_TYPES = frozenset({"thin_cable"})
SMALL_TYPES = frozenset({"small_debris"})
STATION_COLOURED_TYPES = frozenset({"station_patch"})
CABLE_WIDTH_PX = (1.0, 4.0)
"""Silhouette width of a thin cable, pixels."""
SMALL_MAX_PX = 100
"""Largest area of a small object, pixels."""
STATION_SHARE = 0.5
"""Share of an object's pixels with the station behind, above which it is seen against it."""
INVISIBLE_DN = 6.0
"""A pixel of an object in front of space is invisible when its luminance (8-bit display
values of the clean query) is within this of space's level."""
VISIBLE_SHARE = 0.25
"""Objects with less of their pixels visible are marked invisible."""
KINDS = (
    "thin_cable",
    "dark_over_surface",
    "dark_over_space",
    "small",
    "station_coloured",
    "other",
)


def silhouette_width_px(mask: np.ndarray) -> float:
    """Mean width of a thin silhouette: twice its area over its perimeter, pixels.

    For a strip of length L and width w (L >> w) the area is L w and the perimeter about
    2 L. The perimeter is Crofton's estimate from the mask's edge crossings along rows,
    columns and both diagonals (``pi / 8 * (n_row + n_col + (n_diag1 + n_diag2) / sqrt 2)``),
    which, unlike a contour's length, does not depend much on the strip's direction: a
    rasterised strip 2-6 px wide measures within a quarter pixel of its width at most angles.

    Parameters
    ----------
    mask : numpy.ndarray
        (h, w) bool.

    Returns
    -------
    float
        0 for an empty mask.
    """
    m = np.pad(np.asarray(mask, dtype=bool), 1).astype(np.int8)
    area = float(m.sum())
    if area == 0:
        return 0.0
    rows = np.abs(np.diff(m, axis=1)).sum()
    cols = np.abs(np.diff(m, axis=0)).sum()
    diag1 = np.abs(m[1:, 1:] - m[:-1, :-1]).sum()
    diag2 = np.abs(m[1:, :-1] - m[:-1, 1:]).sum()
    perimeter = math.pi / 8.0 * (rows + cols + (diag1 + diag2) / math.sqrt(2.0))
    return 2.0 * area / float(perimeter)


def behind_station_share(mask: np.ndarray, background: np.ndarray) -> float:
    """Share of the object's pixels whose background (labels without it) is the station."""
    pixels = np.count_nonzero(mask)
    if pixels == 0:
        return 0.0
    return float(np.count_nonzero(mask & (background == LABEL_STATION))) / pixels


def visible_fraction(clean: np.ndarray, mask: np.ndarray, background: np.ndarray) -> float:
    """Share of the object's pixels that can be seen at all.

    A pixel in front of the station counts as visible (whether it differs from the hidden
    surface is the detector's problem); one in front of space is visible when its luminance
    exceeds space's level (the median of the space pixels of ``clean``, 0 if none) by more
    than :data:`INVISIBLE_DN`.

    Parameters
    ----------
    clean : numpy.ndarray
        (h, w, 3) uint8 query before the camera model (noise would make space "visible").
    mask : numpy.ndarray
        (h, w) bool, the object's pixels.
    background : numpy.ndarray
        (h, w) labels of the same view without the object.
    """
    pixels = np.count_nonzero(mask)
    if pixels == 0:
        return 0.0
    grey = cv2.cvtColor(clean, cv2.COLOR_RGB2GRAY).astype(np.float64)
    space = (background == LABEL_SPACE) & ~mask
    level = float(np.median(grey[space])) if space.any() else 0.0
    dark = grey <= level + INVISIBLE_DN
    invisible = mask & (background == LABEL_SPACE) & dark
    return 1.0 - float(np.count_nonzero(invisible)) / pixels


def placement_penalty(anomaly: str, mask: np.ndarray, background: np.ndarray) -> float:
    """How far a placement is from what its type is in the bench for; 0 meets it.

    Thin cables must be 1-4 px wide, small objects at most 100 px, station-coloured ones
    mostly against the station. Other types always meet it.
    """
    if anomaly in THIN_TYPES:
        width = silhouette_width_px(mask)
        low, high = CABLE_WIDTH_PX
        return max(0.0, low - width, width - high)
    if anomaly in SMALL_TYPES:
        return max(0.0, np.count_nonzero(mask) - SMALL_MAX_PX) / SMALL_MAX_PX
    if anomaly in STATION_COLOURED_TYPES:
        return max(0.0, STATION_SHARE - behind_station_share(mask, background))
    return 0.0


def classify(anomaly: str, mask: np.ndarray, background: np.ndarray) -> str:
    """The kind of an anomalous frame (one of :data:`KINDS`), measured on its masks."""
    if anomaly in THIN_TYPES:
        low, high = CABLE_WIDTH_PX
        if low <= silhouette_width_px(mask) <= high:
            return "thin_cable"
    share = behind_station_share(mask, background)
    if anomaly in DARK_TYPES:
        return "dark_over_surface" if share >= STATION_SHARE else "dark_over_space"
    if np.count_nonzero(mask) <= SMALL_MAX_PX:
        return "small"
    if anomaly in STATION_COLOURED_TYPES and share >= STATION_SHARE:
        return "station_coloured"
    return "other"


def kind_columns(
    anomaly: str, labels: np.ndarray, background: np.ndarray, clean: np.ndarray
) -> dict[str, object]:
    """The ``frames.csv`` columns of an anomalous frame: kind, width, visibility."""
    mask = labels == LABEL_ANOMALY
    fraction = visible_fraction(clean, mask, background)
    columns: dict[str, object] = {
        "kind": classify(anomaly, mask, background),
        "behind_station": round(behind_station_share(mask, background), 4),
        "visible_fraction": round(fraction, 4),
        "visible": int(fraction >= VISIBLE_SHARE),
    }
    if anomaly in THIN_TYPES:
        columns["width_px"] = round(silhouette_width_px(mask), 3)
    return columns


def _material_colour(material: PBRMaterial) -> tuple[np.ndarray, float, float]:
    """Linear RGB, metallic and roughness of a material, its textures averaged."""
    factor = material.baseColorFactor
    colour = np.ones(3) if factor is None else np.asarray(factor, dtype=np.float64)[:3]
    if np.issubdtype(np.asarray(factor if factor is not None else 0.0).dtype, np.integer):
        colour = colour / 255.0
    if material.baseColorTexture is not None:
        texel = np.asarray(material.baseColorTexture.convert("RGB"), dtype=np.float64) / 255.0
        colour = colour * (texel**2.2).reshape(-1, 3).mean(axis=0)
    metallic = 1.0 if material.metallicFactor is None else float(material.metallicFactor)
    roughness = 1.0 if material.roughnessFactor is None else float(material.roughnessFactor)
    if material.metallicRoughnessTexture is not None:
        mr = np.asarray(material.metallicRoughnessTexture.convert("RGB"), dtype=np.float64)
        roughness *= float(mr[..., 1].mean()) / 255.0
        metallic *= float(mr[..., 2].mean()) / 255.0
    return colour, metallic, roughness


def station_palette(model: str | PathLike[str] | trimesh.Scene) -> list[tuple]:
    """The station's materials by the surface area they cover, largest first.

    Returns
    -------
    list of tuple
        ``(name, linear RGB (3,), metallic, roughness, area share)``.
    """
    scene = model if isinstance(model, trimesh.Scene) else trimesh.load(model, force="scene")
    areas: dict[str, float] = {}
    looks: dict[str, tuple] = {}
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        mesh = scene.geometry[name]
        material = getattr(getattr(mesh, "visual", None), "material", None)
        if not isinstance(material, PBRMaterial):
            continue
        scale = abs(np.linalg.det(transform[:3, :3])) ** (2.0 / 3.0)
        key = material.name or name
        areas[key] = areas.get(key, 0.0) + float(mesh.area) * scale
        looks.setdefault(key, _material_colour(material))
    total = sum(areas.values()) or 1.0
    ordered = sorted(areas, key=lambda k: (-areas[k], k))
    return [(k, *looks[k], areas[k] / total) for k in ordered]


def paint_like_station(
    scene: trimesh.Scene, palette: list[tuple], rng: np.random.Generator
) -> trimesh.Scene:
    """A copy of an object's scene with every part in one of the station's materials, drawn
    by area share among those covering at least 10 % of the station."""
    common = [entry for entry in palette if entry[4] >= 0.1] or palette[:1]
    weights = np.array([entry[4] for entry in common])
    name, colour, metallic, roughness, _ = common[
        int(rng.choice(len(common), p=weights / weights.sum()))
    ]
    painted = scene.copy()
    for key in sorted(scene.geometry):
        mesh = scene.geometry[key]
        mesh = trimesh.Trimesh(
            mesh.vertices, mesh.faces, vertex_normals=mesh.vertex_normals, process=False
        )
        mesh.visual = trimesh.visual.TextureVisuals(
            material=PBRMaterial(
                name=f"station_{name}",
                baseColorFactor=(*np.clip(colour, 0.0, 1.0), 1.0),
                metallicFactor=float(np.clip(metallic, 0.0, 1.0)),
                roughnessFactor=float(np.clip(roughness, 0.0, 1.0)),
                doubleSided=True,
            )
        )
        painted.geometry[key] = mesh
    return painted
