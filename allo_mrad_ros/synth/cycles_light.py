"""A light model and materials for the Cycles query that the reference does not share.

The reference renderer reads the model's glTF materials and lights the scene with a point
Sun, a spot lamp and a uniform ambient term. A query path-traced with the same materials
and lamps differs from it only by what path tracing adds; a camera looking at a real station
sees surfaces whose gloss no CAD file states and light no renderer of ours draws. With a
:class:`CyclesLightConfig` the Cycles query departs from the reference in:

* materials: every material's roughness moved away from its glTF value (by a drawn amount,
  either way; a roughness texture is offset through a clamped add) and its specular
  strength (Blender's ``Specular IOR Level``; 0.5 is glTF's 4 % reflectance) drawn anew,
  once per sequence (the station is one object);
* light: Earth-shine, a wide bluish sun lamp from the Earth's direction whose strength is
  drawn per frame (the light bounced off the station itself is what the path tracer adds);
  a disc area light at the camera in place of the arm's spot lamp. The Sun keeps its finite
  disc (:data:`~.cycles.SUN_ANGLE_DEG`).

The draws are plain NumPy (:func:`draw_material_departures`, :func:`draw_earthshine`) so
that they can be checked without Blender; :func:`apply_material_departures` writes them into
Blender's node trees.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from allo_mrad_ros.synth.validation import SynthError, finite_number, number_pair

GLTF_SPECULAR_LEVEL = 0.5
"""Blender's ``Specular IOR Level`` that gives glTF's dielectric reflectance (IOR 1.5)."""
EARTHSHINE_COLOUR = (0.72, 0.84, 1.0)
"""Earth-shine's tint (ocean and cloud, bluer than sunlight)."""
ROUGHNESS_RANGE = (0.02, 1.0)


@dataclass(frozen=True)
class CyclesLightConfig:
    """How the Cycles query's materials and lamps depart from the reference's.

    Parameters
    ----------
    roughness_shift : tuple of float
        Range of the absolute change of each material's roughness; the sign is drawn too,
        and a shift that would leave [0.02, 1] goes the other way.
    specular_level : tuple of float
        Range of each material's ``Specular IOR Level`` (0.5 is the glTF value).
    earthshine : tuple of float
        Range of the Earth-shine lamp's irradiance relative to the Sun's at strength 1,
        drawn per frame; (0, 0) adds none.
    earthshine_angle_deg : float
        Apparent diameter of the Earth-shine lamp (soft: the lit Earth is a wide source).
    area_lamp : bool
        A disc area light at the camera instead of the arm's spot lamp.
    area_lamp_size_m : float
        Diameter of that disc.
    """

    roughness_shift: tuple[float, float] = (0.15, 0.35)
    specular_level: tuple[float, float] = (0.15, 1.0)
    earthshine: tuple[float, float] = (0.02, 0.12)
    earthshine_angle_deg: float = 20.0
    area_lamp: bool = True
    area_lamp_size_m: float = 0.3

    def __post_init__(self) -> None:
        low, high = number_pair(self.roughness_shift, "roughness_shift", 0.0)
        if high > 0.9:
            raise SynthError(f"roughness_shift must lie in [0, 0.9], got {(low, high)}")
        object.__setattr__(self, "roughness_shift", (low, high))
        level = number_pair(self.specular_level, "specular_level", 0.0)
        if level[1] > 1.0:
            raise SynthError(f"specular_level must lie in [0, 1], got {level}")
        object.__setattr__(self, "specular_level", level)
        object.__setattr__(self, "earthshine", number_pair(self.earthshine, "earthshine", 0.0))
        finite_number(self.earthshine_angle_deg, "earthshine_angle_deg", 0.0, 180.0)
        if not isinstance(self.area_lamp, bool):
            raise SynthError(f"area_lamp must be a bool, got {self.area_lamp!r}")
        finite_number(self.area_lamp_size_m, "area_lamp_size_m", 0.01, 5.0)


@dataclass(frozen=True)
class MaterialDeparture:
    """How one material of the Cycles query differs from its glTF values.

    Attributes
    ----------
    roughness_shift : float
        Added to the roughness (clamped to [0.02, 1] in Blender).
    specular_level : float
        Blender's ``Specular IOR Level``.
    """

    roughness_shift: float
    specular_level: float


def shifted_roughness(roughness: float, magnitude: float, sign: float) -> float:
    """The shift applied to ``roughness``: ``sign * magnitude``, or the other way when that
    would leave [0.02, 1] (so the change is never clipped away)."""
    low, high = ROUGHNESS_RANGE
    shift = math.copysign(magnitude, sign)
    if not low <= roughness + shift <= high:
        shift = -shift
    return shift if low <= roughness + shift <= high else (high + low) / 2 - roughness


def draw_material_departures(
    materials: Mapping[str, float], rng: np.random.Generator, config: CyclesLightConfig
) -> dict[str, MaterialDeparture]:
    """Draw each material's departure, in name order.

    Parameters
    ----------
    materials : Mapping[str, float]
        Material name to its glTF roughness (the factor; a textured one's is typically 1).
    rng : numpy.random.Generator
        Source of the draws (three per material).
    config : CyclesLightConfig
        The ranges.

    Returns
    -------
    dict
        Material name to :class:`MaterialDeparture`.
    """
    result = {}
    for name in sorted(materials):
        magnitude = float(rng.uniform(*config.roughness_shift))
        sign = 1.0 if rng.random() < 0.5 else -1.0
        level = float(rng.uniform(*config.specular_level))
        shift = shifted_roughness(float(materials[name]), magnitude, sign)
        result[name] = MaterialDeparture(shift, level)
    return result


def draw_earthshine(rng: np.random.Generator, config: CyclesLightConfig) -> float:
    """The Earth-shine lamp's relative irradiance of one frame."""
    low, high = config.earthshine
    return float(rng.uniform(low, high)) if high > low else low


def _principled(material: object) -> list:
    tree = getattr(material, "node_tree", None)
    if tree is None:
        return []
    return [n for n in tree.nodes if n.type == "BSDF_PRINCIPLED"]


def material_roughness(materials: Iterable[object]) -> dict[str, float]:
    """Each Blender material's roughness as imported (its glTF factor; a linked input's
    default value is the factor the glTF importer multiplies the texture by)."""
    result = {}
    for material in materials:
        for node in _principled(material):
            result[material.name] = float(node.inputs["Roughness"].default_value)
            break
    return result


def apply_material_departures(
    materials: Iterable[object], departures: Mapping[str, MaterialDeparture]
) -> dict[str, tuple[float, float]]:
    """Write the departures into the materials' Principled BSDFs.

    An unlinked roughness gets its new value; a roughness fed by a texture gets a clamped
    add node in between. Returns each material's (roughness or shift, specular level) as
    set, for checking.
    """
    set_values = {}
    for material in materials:
        departure = departures.get(material.name)
        if departure is None:
            continue
        for node in _principled(material):
            rough = node.inputs["Roughness"]
            if rough.is_linked:
                link = rough.links[0]
                add = material.node_tree.nodes.new("ShaderNodeMath")
                add.operation = "ADD"
                add.use_clamp = True
                add.inputs[1].default_value = departure.roughness_shift
                material.node_tree.links.new(link.from_socket, add.inputs[0])
                material.node_tree.links.new(add.outputs[0], rough)
                value = departure.roughness_shift
            else:
                low, high = ROUGHNESS_RANGE
                value = min(high, max(low, rough.default_value + departure.roughness_shift))
                rough.default_value = value
            specular = node.inputs["Specular IOR Level"]
            if not specular.is_linked:
                specular.default_value = departure.specular_level
            set_values[material.name] = (float(value), float(specular.default_value))
    return set_values
