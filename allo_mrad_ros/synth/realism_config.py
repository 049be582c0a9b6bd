"""Settings of the query's departures from a clean render: :class:`RealismConfig`.

The reference MRAD compares against is rendered at evaluation time from the pose, Sun
direction and Sun strength written to ``frames.csv``, with the nominal CAD model and the
reference renderer's display transform. The query stands for a real camera image, so every
way in which a camera image departs from that render is made here, on the query only:

* the light: the Sun's strength and direction and the ambient and spot-lamp levels that lit
  the query differ from the recorded ones (the MRAD paper's lighting variation);
* the surfaces: the as-built station's colours, per-part shifts and albedo texture, and
  textured, worn anomaly objects (the CAD model has flat single-colour materials);
* the camera: exposure, an S-shaped tone curve, saturation, white balance, glare, bloom,
  vignetting, blur and sensor noise.

The pose error between the written and the true pose is a :class:`~.config.SynthConfig`
setting. Defaults are moderate values from camera physics and the ALLO/MRAD protocol, not
tuned against any detector.
"""

from __future__ import annotations

from dataclasses import dataclass

from allo_mrad_ros.synth.validation import SynthError, finite_number, number_pair


@dataclass(frozen=True)
class RealismConfig:
    """How the query image departs from a clean render of the CAD model.

    Parameters
    ----------
    enabled : bool
        False writes the clean render of the nominal model under the recorded light as the
        query (for debugging only).
    exposure_sigma : float
        Standard deviation of the log exposure gain per frame (auto-exposure error).
    read_noise_dn : float
        Read noise in 8-bit digital numbers (DN).
    shot_noise_dn : float
        Shot-noise standard deviation at full scale (255 DN); it scales with sqrt(signal).
    noise_gain : tuple of float
        Range of the per-frame multiplier on both noise terms (sensor gain).
    blur_sigma : float
        Optical blur (Gaussian sigma) in pixels at 1920 pixels of width.
    vignetting : float
        Relative brightness loss in the image corners.
    bloom : float
        Weight of the halo around saturated highlights.
    glare : float
        Weight of the Sun's glare (halo, diffraction spikes, ghosts) when the Sun is in view.
    material_variation : float
        Relative spread of the as-built station's material colours and roughness around
        the CAD model's (one draw per material and sequence: the real station is one object).
    part_variation : float
        Standard deviation of the log colour gain of each station part (panel batches,
        ageing, contamination), on top of its material's; per channel, half of it shared
        by the three channels.
    texture_contrast : float
        Standard deviation of the log albedo of the surface texture (stains, wrinkles,
        weave) on the station and on anomaly objects; 0 leaves surfaces untextured.
    texture_tile_m : float
        Size of one texture tile on the station, metres; tile edges carry panel seams.
    seam_darkening : float
        Relative albedo loss along panel seams.
    tone_contrast : tuple of float
        Range of the exponent of the S-shaped tone curve ``d**k / (d**k + (1 - d)**k)``
        applied to display values (1 is no curve); drawn once per sequence, as a camera's
        or a path tracer's view transform is fixed.
    saturation : tuple of float
        Range of the colour saturation factor (1 unchanged), once per sequence.
    white_balance_sigma : float
        Standard deviation of the log gain of the red and blue channels against green per
        frame (white balance error), clipped at three times the value.
    sun_strength_sigma : float
        Standard deviation of the log ratio of the Sun strength lighting the query to the
        recorded one, per frame.
    sun_direction_sigma_deg : float
        Standard deviation of the angle between the Sun direction lighting the query and
        the recorded one, per axis, per frame (station attitude error).
    ambient_gain, spot_gain : tuple of float
        Ranges of the query's ambient (Earth-shine) and arm-lamp levels relative to the
        reference renderer's, once per sequence.
    anomaly_albedo_sigma : float
        Standard deviation of the log colour gain of each anomaly object's parts (wear,
        fading, the lighting of where it has been).
    """

    enabled: bool = True
    exposure_sigma: float = 0.12
    read_noise_dn: float = 1.2
    shot_noise_dn: float = 3.0
    noise_gain: tuple[float, float] = (0.8, 1.5)
    blur_sigma: float = 0.6
    vignetting: float = 0.12
    bloom: float = 0.06
    glare: float = 1.0
    material_variation: float = 0.08
    part_variation: float = 0.06
    texture_contrast: float = 0.10
    texture_tile_m: float = 2.0
    seam_darkening: float = 0.2
    tone_contrast: tuple[float, float] = (1.1, 1.4)
    saturation: tuple[float, float] = (0.8, 1.05)
    white_balance_sigma: float = 0.03
    sun_strength_sigma: float = 0.15
    sun_direction_sigma_deg: float = 1.0
    ambient_gain: tuple[float, float] = (0.5, 2.0)
    spot_gain: tuple[float, float] = (0.7, 1.3)
    anomaly_albedo_sigma: float = 0.1

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, bool):
            raise SynthError(f"realism enabled must be a bool, got {self.enabled!r}")
        finite_number(self.exposure_sigma, "exposure_sigma", 0.0, 1.0)
        finite_number(self.read_noise_dn, "read_noise_dn", 0.0, 50.0)
        finite_number(self.shot_noise_dn, "shot_noise_dn", 0.0, 50.0)
        object.__setattr__(self, "noise_gain", number_pair(self.noise_gain, "noise_gain", 0.0))
        finite_number(self.blur_sigma, "blur_sigma", 0.0, 10.0)
        finite_number(self.vignetting, "vignetting", 0.0, 0.9)
        finite_number(self.bloom, "bloom", 0.0, 1.0)
        finite_number(self.glare, "glare", 0.0, 10.0)
        finite_number(self.material_variation, "material_variation", 0.0, 0.5)
        finite_number(self.part_variation, "part_variation", 0.0, 0.5)
        finite_number(self.texture_contrast, "texture_contrast", 0.0, 0.5)
        finite_number(self.texture_tile_m, "texture_tile_m", 0.05, 100.0)
        finite_number(self.seam_darkening, "seam_darkening", 0.0, 0.9)
        tone = number_pair(self.tone_contrast, "tone_contrast", 0.5)
        if tone[1] > 3.0:
            raise SynthError(f"tone_contrast must be <= 3, got {self.tone_contrast!r}")
        object.__setattr__(self, "tone_contrast", tone)
        saturation = number_pair(self.saturation, "saturation", 0.0)
        if saturation[1] > 2.0:
            raise SynthError(f"saturation must be <= 2, got {self.saturation!r}")
        object.__setattr__(self, "saturation", saturation)
        finite_number(self.white_balance_sigma, "white_balance_sigma", 0.0, 0.3)
        finite_number(self.sun_strength_sigma, "sun_strength_sigma", 0.0, 1.0)
        finite_number(self.sun_direction_sigma_deg, "sun_direction_sigma_deg", 0.0, 20.0)
        object.__setattr__(
            self, "ambient_gain", number_pair(self.ambient_gain, "ambient_gain", 0.0)
        )
        object.__setattr__(self, "spot_gain", number_pair(self.spot_gain, "spot_gain", 0.0))
        finite_number(self.anomaly_albedo_sigma, "anomaly_albedo_sigma", 0.0, 0.5)
