"""Synthetic laparoscope captures with known truth: `ctjax synth` and `synthesize`.

Without texture and effects the images are exactly the paper's model (eq. 1-2) under a
light co-located with the camera, with constant intensity, plus Gaussian noise and 8-bit
quantisation (highlights saturate). Every effect of the reflectance, light and camera
modules can be switched on, so that estimators and diagnostics can be tested against
known truth.
"""

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._camera import Camera
from .._errors import ParameterError
from .._render import apply_effects, render_columns
from ..effects import Ambient, CameraGamma
from ..io import Frame, write_capture
from ..lights import ColocatedLight, InverseSquare, PointLight, SpotFalloff
from ..lobes import (
    BRDF,
    GGX,
    Beckmann,
    GeometricAttenuation,
    Lambertian,
    SchlickFresnel,
    Specular,
)
from ._organ import OrganSurface, cast_rays
from ._texture import sample_texture, tissue_texture
from ._trajectory import exploration

# Default tissue: reddish diffuse albedo, white highlights (F is the same in every channel).
DEFAULT_RHO_TILDE = (2.4, 1.1, 0.85)
DEFAULT_F_TILDE = (0.3, 0.3, 0.3)
DEFAULT_SIGMA = 0.2
WORKING_DISTANCE_MM = 70.0


@dataclasses.dataclass(frozen=True)
class SynthOptions:
    """What `synthesize` makes. Intensities are linear, 1.0 = 8-bit level 255.

    Effects (all off by default, which gives the paper's exact model):

    - `light_offset_mm`: a point light at this camera-frame position instead of the centre.
    - `inverse_square`: irradiance falls as (70 mm / distance)^2.
    - `spot_exponent`: angular falloff cos^k around the optical axis.
    - `camera_gamma`: pixel = radiance^(1/gamma).
    - `ambient`: constant radiance added per channel.
    - `fresnel_f0`: Schlick's Fresnel angle dependence with this F0, at the angle
      `fresnel_cosine` ("half": V.H, Cook-Torrance; "normal": N.V).
    - `geometric_attenuation`: Cook-Torrance's G.
    - `ggx`: GGX instead of Beckmann, with alpha = sigma.
    - `second_lobe`: (sigma_2, fraction): a second Beckmann lobe with F_tilde * fraction.
    """

    width: int = 320
    height: int = 256
    frames: int = 5
    seed: int = 0
    texture: bool = True
    texture_contrast: float = 1.0  # scales the texture's deviation from 1 (0: none)
    noise_levels: float = 1.0
    bits: int = 8
    rho_tilde: tuple[float, float, float] = DEFAULT_RHO_TILDE
    F_tilde: tuple[float, float, float] = DEFAULT_F_TILDE
    sigma: float = DEFAULT_SIGMA
    focal_px: float | None = None  # default: 0.9 * width (a ~58 degree field of view)
    light_offset_mm: tuple[float, float, float] | None = None
    inverse_square: bool = False
    spot_exponent: float | None = None
    camera_gamma: float | None = None
    ambient: tuple[float, float, float] | None = None
    fresnel_f0: float | None = None
    fresnel_cosine: str = "half"
    geometric_attenuation: bool = False
    ggx: bool = False
    second_lobe: tuple[float, float] | None = None

    def __post_init__(self):
        problems = []
        if self.width < 16 or self.height < 16:
            problems.append(f"image size {self.width}x{self.height} (at least 16x16)")
        if not (np.isfinite(self.texture_contrast) and 0 <= self.texture_contrast <= 1):
            problems.append(f"texture_contrast={self.texture_contrast} (in [0, 1])")
        if self.frames < 1:
            problems.append(f"frames={self.frames} (at least 1)")
        if not np.isfinite(self.noise_levels) or self.noise_levels < 0:
            problems.append(f"noise_levels={self.noise_levels} (>= 0)")
        if self.bits not in (8, 16):
            problems.append(f"bits={self.bits} (8 or 16)")
        if not (np.isfinite(self.sigma) and 1e-5 <= self.sigma <= 1):
            problems.append(f"sigma={self.sigma} (in [1e-5, 1])")
        for name in ("rho_tilde", "F_tilde"):
            value = np.asarray(getattr(self, name), float)
            if value.shape != (3,) or not np.all(np.isfinite(value)) or np.any(value < 0):
                problems.append(f"{name}={getattr(self, name)} (three values >= 0)")
        if problems:
            raise ParameterError("synth: invalid " + "; ".join(problems))

    @property
    def effects(self) -> dict:
        """The effects switched on, with their parameters (as written to truth.json)."""
        out = {}
        if self.light_offset_mm is not None:
            out["light_offset"] = {"position_mm": list(map(float, self.light_offset_mm))}
        if self.inverse_square:
            out["inverse_square"] = {"reference_mm": WORKING_DISTANCE_MM}
        if self.spot_exponent is not None:
            out["spot_falloff"] = {"exponent": float(self.spot_exponent), "axis": [0, 0, 1]}
        if self.camera_gamma is not None:
            out["camera_gamma"] = {"gamma": float(self.camera_gamma)}
        if self.ambient is not None:
            out["ambient"] = {"level": list(map(float, self.ambient))}
        if self.fresnel_f0 is not None:
            out["fresnel_schlick"] = {"f0": float(self.fresnel_f0), "cosine": self.fresnel_cosine}
        if self.geometric_attenuation:
            out["geometric_attenuation"] = {}
        if self.ggx:
            out["ggx"] = {"alpha": float(self.sigma)}
        if self.second_lobe is not None:
            sigma2, fraction = self.second_lobe
            out["second_lobe"] = {
                "sigma": float(sigma2),
                "F_tilde": [float(f * fraction) for f in self.F_tilde],
            }
        return out


def scene_model(options: SynthOptions):
    """(brdf, light, effects) of the synthetic scene: the paper's model plus the options."""
    factors = []
    if options.fresnel_f0 is not None:
        factors.append(SchlickFresnel(options.fresnel_f0, options.fresnel_cosine))
    if options.geometric_attenuation:
        factors.append(GeometricAttenuation())
    distribution = GGX(options.sigma) if options.ggx else Beckmann(options.sigma)
    lobes = [
        Lambertian(options.rho_tilde),
        Specular(options.F_tilde, distribution, tuple(factors)),
    ]
    if options.second_lobe is not None:
        sigma2, fraction = options.second_lobe
        lobes.append(
            Specular(np.asarray(options.F_tilde) * fraction, Beckmann(sigma2), tuple(factors))
        )
    falloff = []
    if options.inverse_square:
        falloff.append(InverseSquare(WORKING_DISTANCE_MM))
    if options.spot_exponent is not None:
        falloff.append(SpotFalloff(options.spot_exponent))
    if options.light_offset_mm is not None:
        light = PointLight(np.asarray(options.light_offset_mm, float), falloff=tuple(falloff))
    else:
        light = ColocatedLight(falloff=tuple(falloff))
    effects = []
    if options.ambient is not None:
        effects.append(Ambient(options.ambient))
    if options.camera_gamma is not None:
        effects.append(CameraGamma(options.camera_gamma))
    return BRDF(*lobes), light, tuple(effects)


def synthetic_camera(options: SynthOptions) -> Camera:
    focal = options.focal_px if options.focal_px is not None else 0.9 * options.width
    return Camera(
        options.width,
        options.height,
        focal,
        focal,
        (options.width - 1) / 2,
        (options.height - 1) / 2,
    )


def _render_frame(brdf, light, effects, camera, depth, normals, albedo_map):
    """Linear RGB of one frame: the diffuse lobes' weights are multiplied by the texture."""
    columns = render_columns(brdf, light, camera, jnp.asarray(normals), jnp.asarray(depth))
    weights = brdf.weights  # (K, 3)
    diffuse = jnp.array([isinstance(lobe, Lambertian) for lobe in brdf.lobes])
    texture = jnp.where(diffuse[:, None, None, None], jnp.asarray(albedo_map)[None], 1.0)
    rgb = jnp.einsum("hwk,khwc,kc->hwc", columns, texture, weights)
    return jax.vmap(jax.vmap(lambda pixel: apply_effects(effects, pixel)))(rgb)


def synthesize(out: str | Path, options: SynthOptions = SynthOptions()) -> Path:
    """Generate a synthetic laparoscope capture into folder `out`; returns the folder.

    Writes the capture format (camera.json, images/, depth/, normals/, poses.json) and
    truth.json with `rho_tilde`, `F_tilde`, `sigma` (the paper's scaled weights, linear
    units where 1.0 is 8-bit level 255), the poses, the noise and the effects used.
    """
    # The model first: a bad parameter fails before any work. No timings in truth.json,
    # so that the same options give byte-identical captures.
    brdf, light, effects = scene_model(options)
    rng = np.random.default_rng(options.seed)
    surface_rng, texture_rng, path_rng, noise_rng = rng.spawn(4)
    surface = OrganSurface.random(surface_rng, WORKING_DISTANCE_MM)
    texture = tissue_texture(texture_rng) if options.texture else None
    poses = exploration(options.frames, path_rng, WORKING_DISTANCE_MM)
    camera = synthetic_camera(options)
    frames = []
    saturated = []
    for index, pose in enumerate(poses):
        depth, normals, points_world = cast_rays(surface, camera, pose)
        # Render from exactly what is stored (float32), so the files are self-consistent.
        depth = depth.astype(np.float32)
        normals = normals.astype(np.float32)
        albedo_map = (
            sample_texture(texture, points_world)
            if texture is not None
            else np.ones((*depth.shape, 3), np.float32)
        )
        if options.texture_contrast != 1:
            albedo_map = 1 + np.float32(options.texture_contrast) * (albedo_map - 1)
        linear = np.asarray(_render_frame(brdf, light, effects, camera, depth, normals, albedo_map))
        noisy = linear + noise_rng.normal(0, options.noise_levels / 255, linear.shape)
        top = 255 if options.bits == 8 else 65535
        quantised = np.round(np.clip(noisy, 0, 1) * top) / top
        saturated.append(float(np.mean(np.any(quantised >= 1, axis=-1))))
        frames.append(
            Frame(f"frame_{index:03d}", quantised.astype(np.float32), depth, normals, pose)
        )
    truth = {
        "rho_tilde": list(map(float, options.rho_tilde)),
        "F_tilde": list(map(float, options.F_tilde)),
        "sigma": float(options.sigma),
        "units": "linear intensity, 1.0 = 8-bit level 255 (light intensity folded in)",
        "model": "paper eq. (1)-(2): rho_tilde/pi (N.L) + F_tilde D / (pi (N.L)(N.V)), "
        "Beckmann D = exp(-tan^2 a / sigma^2) / (sigma^2 cos^4 a)",
        "light": {
            "model": "point" if options.light_offset_mm is not None else "colocated",
            "position_mm": list(map(float, options.light_offset_mm or (0, 0, 0))),
            "intensity": 1.0,
        },
        "effects": options.effects,
        "noise_levels": float(options.noise_levels),
        "bits": options.bits,
        "texture": options.texture,
        "texture_contrast": options.texture_contrast,
        "texture_note": "textured captures multiply rho_tilde per pixel by a map of mean 1",
        "seed": options.seed,
        "saturated_fraction": saturated,
        "organ": {"base_mm": surface.base_mm, "radius_mm": surface.radius_mm},
        "poses": {frame.name: frame.pose.tolist() for frame in frames},
    }
    return write_capture(out, camera, frames, truth, bits=options.bits)
