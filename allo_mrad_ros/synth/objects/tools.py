"""EVA tools lost during spacewalks: a hand drill, a pistol-grip tool, a wrench, a glove."""

from __future__ import annotations

import numpy as np

from .base import Part
from .shapes import ellipsoid, rod, rotation_about, slab, transformed, tube


def drill(rng: np.random.Generator) -> list[Part]:
    """A cordless hand drill: motor body, chuck and bit, grip and battery pack."""
    body_len = rng.uniform(0.18, 0.26)
    body_r = rng.uniform(0.03, 0.042)
    grip_len = rng.uniform(0.12, 0.17)
    bit_len = rng.uniform(0.06, 0.15)
    colour = str(rng.choice(["yellow_plastic", "green_plastic", "grey_plastic"]))
    body = rod((0.0, 0, 0), (body_len, 0, 0), body_r, 20)
    rear = transformed(ellipsoid((0.03, body_r, body_r)), None, (0.0, 0.0, 0.0))
    chuck = rod((body_len, 0, 0), (body_len + 0.05, 0, 0), 0.55 * body_r, 16)
    bit = rod((body_len + 0.05, 0, 0), (body_len + 0.05 + bit_len, 0, 0), 0.005, 8)
    # The grip leans back by 10-20 degrees, as on real drills.
    lean = rotation_about((0.0, 1.0, 0.0), -rng.uniform(0.17, 0.35))
    grip_centre = np.array([0.4 * body_len, 0.0, -grip_len / 2])
    grip = slab((0, 0, 0), (0.045, 0.04, grip_len), lean)
    grip.apply_translation(grip_centre)
    foot = grip_centre + lean @ np.array([0.0, 0.0, -grip_len / 2])
    battery = slab(foot + np.array([0.0, 0.0, -0.03]), (0.1, 0.075, 0.055))
    trigger = slab((0.4 * body_len + 0.03, 0.0, -0.03), (0.015, 0.015, 0.03))
    return [
        Part(body, colour, smooth=True),
        Part(rear, colour, smooth=True),
        Part(grip, "black_plastic"),
        Part(battery, "black_plastic"),
        Part(trigger, "grey_plastic"),
        Part(chuck, "dark_metal", smooth=True),
        Part(bit, "aluminium", smooth=True),
    ]


def pistol_grip_tool(rng: np.random.Generator) -> list[Part]:
    """NASA's pistol-grip tool: a boxy powered driver with a long socket extension."""
    length = rng.uniform(0.25, 0.32)
    body = slab((length / 2, 0, 0), (length, 0.075, 0.1))
    grip_len = rng.uniform(0.13, 0.17)
    lean = rotation_about((0.0, 1.0, 0.0), -rng.uniform(0.1, 0.3))
    grip = slab((0, 0, 0), (0.05, 0.05, grip_len), lean)
    grip.apply_translation((0.3 * length, 0.0, -0.05 - grip_len / 2 + 0.01))
    display = slab((0.75 * length, 0.0, 0.055), (0.08, 0.05, 0.012))
    ext_len = rng.uniform(0.1, 0.3)
    extension = rod((length, 0, 0), (length + ext_len, 0, 0), 0.008, 10)
    socket = rod((length + ext_len, 0, 0), (length + ext_len + 0.04, 0, 0), 0.016, 6)
    ring = tube(
        np.array([[0.0, 0.012 * np.cos(a), 0.012 * np.sin(a)] for a in np.linspace(0, 6.0, 24)])
        + np.array([-0.005, 0.0, -0.06 - grip_len]),
        0.004,
        8,
    )
    return [
        Part(body, "grey_plastic"),
        Part(grip, "black_plastic"),
        Part(display, "carbon"),
        Part(extension, "aluminium", smooth=True),
        Part(socket, "dark_metal", smooth=True),
        Part(ring, "aluminium", smooth=True),
    ]


def wrench(rng: np.random.Generator) -> list[Part]:
    """A large EVA ratchet wrench: flat handle, ratchet head, open jaw at the other end."""
    length = rng.uniform(0.35, 0.5)
    width = rng.uniform(0.03, 0.045)
    thickness = rng.uniform(0.012, 0.018)
    handle = slab((0.0, 0, 0), (length, width, thickness))
    head = rod((length / 2, 0, -thickness), (length / 2, 0, thickness), 1.2 * width, 24)
    socket = rod((length / 2, 0, thickness), (length / 2, 0, thickness + 0.03), 0.45 * width, 6)
    jaw_a = slab((-length / 2 - 0.025, 0.6 * width, 0), (0.06, 0.4 * width, thickness))
    jaw_b = slab((-length / 2 - 0.025, -0.6 * width, 0), (0.06, 0.4 * width, thickness))
    grip = slab((0.05 * length, 0, 0), (0.45 * length, 1.1 * width, 1.3 * thickness))
    metal = "aluminium" if rng.random() < 0.7 else "dark_metal"
    return [
        Part(handle, metal),
        Part(head, metal, smooth=True),
        Part(socket, "dark_metal"),
        Part(jaw_a, metal),
        Part(jaw_b, metal),
        Part(grip, "rubber"),
    ]


def glove(rng: np.random.Generator) -> list[Part]:
    """An EVA glove: padded palm, four curled fingers, thumb, gauntlet cuff and wrist ring."""
    palm = ellipsoid((0.055, 0.022, 0.065))
    curl = rng.uniform(0.1, 0.9)  # 0 flat, 1 a loose fist
    parts = [Part(palm, "white_cloth", smooth=True)]
    for i, dx in enumerate((-0.036, -0.012, 0.012, 0.036)):
        length = 0.075 + 0.01 * (1 - abs(i - 1.5) / 1.5) + rng.uniform(-0.005, 0.005)
        base = np.array([dx, 0.0, 0.06])
        mid = base + np.array([0.0, -0.45 * length * np.sin(curl * 0.8), 0.5 * length])
        tip = mid + np.array([0.0, -0.5 * length * np.sin(curl * 1.6), 0.5 * length * np.cos(curl)])
        finger = tube(np.vstack([base, mid, tip]), 0.012, 12)
        parts.append(Part(finger, "white_cloth", smooth=True))
        parts.append(
            Part(transformed(ellipsoid((0.012, 0.012, 0.012), 1), None, tip), "rubber", smooth=True)
        )
    thumb_base = np.array([0.06, -0.005, 0.0])
    thumb_tip = thumb_base + np.array([0.04, -0.03 * curl, 0.05])
    parts.append(
        Part(tube(np.vstack([thumb_base, thumb_tip]), 0.014, 12), "white_cloth", smooth=True)
    )
    cuff_len = rng.uniform(0.1, 0.16)
    cuff = rod((0.0, 0.0, -0.05), (0.0, 0.0, -0.05 - cuff_len), 0.055, 24)
    cuff.apply_scale((1.0, 0.8, 1.0))
    ring = rod((0.0, 0.0, -0.05 - cuff_len), (0.0, 0.0, -0.08 - cuff_len), 0.06, 24)
    ring_material = "blue_anodised" if rng.random() < 0.5 else "aluminium"
    parts += [Part(cuff, "white_cloth", smooth=True), Part(ring, ring_material, smooth=True)]
    return parts
