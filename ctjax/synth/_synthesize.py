"""Synthetic laparoscope captures with known truth: `ctjax synth` and `synthesize`.

Without texture and effects the images are exactly the paper's model (eq. 1-2) under a
light co-located with the camera, with constant intensity, plus Gaussian noise and 8-bit
quantisation (highlights saturate). Every effect of the reflectance, light and camera
modules can be switched on, so that estimators and diagnostics can be tested against
known truth.
"""

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._camera import Camera
from .._candidate import AbstractCandidate, discover_candidates
from .._errors import ParameterError
from .._json import array_fields, named_parameters
from .._model import ShadingModel
from .._render import Site, apply_effects, render_columns
from ..io import Frame, write_capture
from ..io._atomic import atomic_write_npy
from ..io._stereo import StereoRig
from ..lights import ColocatedLight, PointLight
from ..lobes import Lambertian, cook_torrance_brdf
from ._organ import OrganSurface, cast_rays
from ._texture import sample_field, sample_texture, seeded_texture
from ._trajectory import exploration

# Default tissue: reddish diffuse albedo, white highlights (F is the same in every channel).
DEFAULT_RHO_TILDE = (2.4, 1.1, 0.85)
DEFAULT_F_TILDE = (0.3, 0.3, 0.3)
DEFAULT_SIGMA = 0.2
WORKING_DISTANCE_MM = 70.0
# Sparkles (`SynthOptions.sparkles`): each facet's own sharp lobe, and the default scale
# (px) over which a facet's tilt is correlated (a sparkle spans a few pixels), as in
# benchmarks/lobe_ideas.py's `sparkly_capture`.
SPARKLE_MICRO_SIGMA = 0.06
SPARKLE_CORRELATION_PX = 1.5


def synth_effects() -> dict:
    """The effects synth can hide in a capture, by name: every candidate (see
    `ctjax.diagnostics.CANDIDATES`) that declares how to synthesise itself."""
    return {
        c.name: c
        for c in discover_candidates()
        if type(c).synthesize is not AbstractCandidate.synthesize
    }


# The largest side rendered: 4096 x 4096 x 3 float64 channels and their intermediates are
# gigabytes already (100000 x 100000 asked for 240 GB and failed in numpy).
MAX_SIDE_PX = 4096


@dataclasses.dataclass(frozen=True)
class SynthOptions:
    """What `synthesize` makes. Intensities are linear, 1.0 = 8-bit level 255.

    `effects`: the effects beyond the paper's model, by name, with their true values (none
    by default, which gives the paper's exact model), e.g.
    `{"light_offset": (6.0, 0.0, 0.0), "inverse_square": True, "camera_gamma": 2.2}`.
    Each effect is declared beside its physics (its candidate's `synthesize`): a point light
    at an offset (`light_offset`, mm), `inverse_square` (1 at 70 mm), `spot_falloff`
    (cos^k), `camera_gamma`, `ambient` (R, G, B), `fresnel_schlick` (F0, or (F0, "half" |
    "normal")), `geometric_attenuation`, `ggx` (alpha = sigma), `second_lobe`
    (sigma_2, fraction of F_tilde); `synth_effects()` lists them.

    `sparkles`: highlights as sparkles, as wet tissue shows them: every pixel sees one
    facet, its normal the surface's tilted by a Beckmann slope of roughness `sigma`
    (correlated over `sparkle_px` pixels, drawn anew each frame), lit by a sharp lobe
    (`SPARKLE_MICRO_SIGMA`, the specular lobes' roughness); the stored normals stay the
    surface's. The lobe a pixel-averaged model sees has the effective roughness
    `effective_sigma` (truth.json's `sigma`). `sparkles_attached`: the facets belong to the
    tissue (one tilt field over the world's (x, y), as the texture), so a sparkle stays on
    its surface point from frame to frame while the scope's H stays near its facet, as on
    real wet tissue (`benchmarks/facet_normals.py`); implies `sparkles`. `sparkle_px`:
    the facets' correlation length (pixels at the working distance): at the default 1.5 a
    tracked point's four bilinear pixels see different facets (a point's lobe is wider
    than `SPARKLE_MICRO_SIGMA`), at 6 they share one.
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
    effects: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    # A stereo laparoscope: the right camera this far right of the left one (mm), parallel,
    # the same intrinsics; the light stays at the left lens. None: one camera.
    stereo_mm: float | None = None
    sparkles: bool = False
    sparkles_attached: bool = False
    sparkle_px: float = SPARKLE_CORRELATION_PX

    def __post_init__(self):
        if self.sparkles_attached and not self.sparkles:
            object.__setattr__(self, "sparkles", True)
        problems = []
        if not (16 <= self.width <= MAX_SIDE_PX and 16 <= self.height <= MAX_SIDE_PX):
            problems.append(
                f"image size {self.width}x{self.height} (from 16x16 to {MAX_SIDE_PX}x{MAX_SIDE_PX})"
            )
        if self.seed < 0:
            problems.append(f"seed={self.seed} (>= 0)")
        if not (np.isfinite(self.texture_contrast) and 0 <= self.texture_contrast <= 1):
            problems.append(f"texture_contrast={self.texture_contrast} (in [0, 1])")
        if self.frames < 1:
            problems.append(f"frames={self.frames} (at least 1)")
        if not np.isfinite(self.noise_levels) or self.noise_levels < 0:
            problems.append(f"noise_levels={self.noise_levels} (>= 0)")
        if self.stereo_mm is not None and not (
            np.isfinite(self.stereo_mm) and 0 < self.stereo_mm < 0.5 * WORKING_DISTANCE_MM
        ):
            problems.append(f"stereo_mm={self.stereo_mm} (a baseline in (0, 35) mm)")
        if not (np.isfinite(self.sparkle_px) and 0.5 <= self.sparkle_px <= 50):
            problems.append(f"sparkle_px={self.sparkle_px} (in [0.5, 50])")
        if self.bits not in (8, 16):
            problems.append(f"bits={self.bits} (8 or 16)")
        if not (np.isfinite(self.sigma) and 1e-5 <= self.sigma <= 1):
            problems.append(f"sigma={self.sigma} (in [1e-5, 1])")
        for name in ("rho_tilde", "F_tilde"):
            value = np.asarray(getattr(self, name), float)
            if value.shape != (3,) or not np.all(np.isfinite(value)) or np.any(value < 0):
                problems.append(f"{name}={getattr(self, name)} (three values >= 0)")
        known = synth_effects()
        unknown = sorted(set(self.effects) - set(known))
        if unknown:
            problems.append(f"effects {unknown} (known: {', '.join(known)})")
        if problems:
            raise ParameterError("synth: invalid " + "; ".join(problems))


def effective_sigma(options: SynthOptions) -> float:
    """The roughness of the lobe the scene shows a pixel-averaged model: `sigma`, or with
    `sparkles` the facets' and their own lobe's combined, hypot(sigma, SPARKLE_MICRO_SIGMA)
    (Beckmann slopes add in variance)."""
    if options.sparkles:
        return float(np.hypot(options.sigma, SPARKLE_MICRO_SIGMA))
    return float(options.sigma)


def _paper_scene(options: SynthOptions, sigma: float | None = None) -> ShadingModel:
    sigma = effective_sigma(options) if sigma is None else sigma
    return ShadingModel(
        cook_torrance_brdf(options.rho_tilde, options.F_tilde, sigma), ColocatedLight()
    )


def _context(options: SynthOptions) -> dict:
    """What a candidate's `synthesize` may need of the capture."""
    camera = synthetic_camera(options)
    return {
        "working_distance_mm": WORKING_DISTANCE_MM,
        "frames": options.frames,
        "seed": options.seed,
        "principal_point": (float(camera.cx), float(camera.cy)),
        "focal_px": (float(camera.fx), float(camera.fy)),
    }


def scene_model(options: SynthOptions, *, sigma: float | None = None) -> ShadingModel:
    """The synthetic scene's model: the paper's, with each effect added at its true value
    (in the order of their names, which puts a falloff before the light that keeps it).
    Its roughness is `effective_sigma` (or `sigma`: the facets' own lobe, which renders
    the sparkles)."""
    model = _paper_scene(options, sigma)
    known = synth_effects()
    context = _context(options)
    for name in sorted(options.effects):
        model = known[name].synthesize(model, options.effects[name], context)
    return model


def effects_truth(options: SynthOptions) -> dict:
    """Each effect's parameters as the scene has them (truth.json's `effects`): the array
    fields it added or changed, by their dotted names (`light.position_mm`...)."""
    known = synth_effects()
    context = _context(options)
    out = {}
    for name in sorted(options.effects):
        base = _paper_scene(options)
        fields = array_fields(base)
        added = array_fields(known[name].synthesize(base, options.effects[name], context))
        out[name] = {k: v for k, v in added.items() if fields.get(k) != v}
    return out


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


def _with_effects(effects, rgb, frame: int):
    """The image effects applied to a rendered frame's linear RGB (H, W, 3)."""
    if not effects:
        return rgb
    height, width = rgb.shape[:2]
    u = jnp.broadcast_to(jnp.arange(width, dtype=rgb.dtype), (height, width))
    v = jnp.broadcast_to(jnp.arange(height, dtype=rgb.dtype)[:, None], (height, width))
    one = lambda x, u, v: apply_effects(effects, x, Site((u, v), jnp.asarray(frame)))  # noqa: E731
    return jax.vmap(jax.vmap(one))(rgb, u, v)


def _render_frame(model: ShadingModel, camera, depth, normals, albedo_map, frame: int, facets=None):
    """Linear RGB of frame `frame`: the diffuse lobes' weights are multiplied by the
    texture; with `facets` (H, W, 3), the other lobes are lit on them (sparkles)."""
    brdf = model.brdf
    columns = render_columns(brdf, model.light, camera, jnp.asarray(normals), jnp.asarray(depth))
    weights = brdf.weights  # (K, 3)
    diffuse = jnp.array([isinstance(lobe, Lambertian) for lobe in brdf.lobes])
    if facets is not None:
        lit = render_columns(brdf, model.light, camera, jnp.asarray(facets), jnp.asarray(depth))
        columns = jnp.where(diffuse, columns, lit)
    texture = jnp.where(diffuse[:, None, None, None], jnp.asarray(albedo_map)[None], 1.0)
    rgb = jnp.einsum("hwk,khwc,kc->hwc", columns, texture, weights)
    return _with_effects(model.effects, rgb, frame)


def _facet_normals(
    normals: np.ndarray, sigma: float, correlation_px: float, rng: np.random.Generator
) -> np.ndarray:
    """(H, W, 3) float32: each pixel's facet, the surface's normal tilted by a Beckmann
    slope of roughness `sigma` (each tangent slope Gaussian of variance sigma^2 / 2),
    correlated over `correlation_px`; NaN where the normal is."""
    import cv2

    h, w = normals.shape[:2]
    slopes = []
    for _ in range(2):
        z = cv2.GaussianBlur(rng.normal(size=(h, w)), (0, 0), correlation_px)
        slopes.append(z / z.std() * sigma / np.sqrt(2))
    return _tilted(normals, slopes)


def _tissue_slopes(
    sigma: float, correlation_px: float, pixel_mm: float, rng: np.random.Generator
) -> list:
    """Two slope fields over the texture's world (x, y) square (float32, read by
    `sample_texture`), Gaussian of variance sigma^2 / 2 each, correlated over
    `correlation_px` pixels at the working distance: facets of the tissue."""
    import cv2

    from ._texture import RESOLUTION, TEXEL_MM

    slopes = []
    for _ in range(2):
        z = rng.normal(size=(RESOLUTION, RESOLUTION))
        z = cv2.GaussianBlur(z, (0, 0), correlation_px * pixel_mm / TEXEL_MM)
        slopes.append((z / z.std() * sigma / np.sqrt(2)).astype(np.float32))
    return slopes


def _tilted(normals: np.ndarray, slopes, rotation: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) float32: the normals tilted by two tangent slopes (H, W) each. The
    tangents are the normal's crossed with the y axis of the normals' frame, or, with
    `rotation` (the camera-to-world rotation of camera-frame normals), of the world's: the
    same slopes then tilt a surface point's normal to the same world direction from every
    pose (facets of the tissue), where the camera's frame would turn them with its roll."""
    n = normals.astype(np.float64)
    if rotation is not None:
        n = n @ np.asarray(rotation, np.float64).T  # to the world
    t1 = np.cross(n, np.array([0.0, 1.0, 0.0]))
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.cross(n, t1)
    facet = n - slopes[0][..., None] * t1 - slopes[1][..., None] * t2
    if rotation is not None:
        facet = facet @ np.asarray(rotation, np.float64)  # back to the camera's frame
    return (facet / np.linalg.norm(facet, axis=-1, keepdims=True)).astype(np.float32)


def _stereo_rig(options: SynthOptions, camera: Camera) -> StereoRig | None:
    """The synthetic stereo rig: the right camera `stereo_mm` to the right, parallel."""
    if options.stereo_mm is None:
        return None
    return StereoRig(camera, np.eye(3), np.array([-options.stereo_mm, 0.0, 0.0]))


def _seen_from_the_right(model: ShadingModel, rig: StereoRig) -> ShadingModel:
    """The scene's model in the right camera's frame: the light where it is, at the left
    lens (or at its offset from it), with its falloffs."""
    light = model.light
    if not isinstance(light, ColocatedLight | PointLight):
        raise ParameterError(
            f"synth --stereo: the light must be at or beside the lens, got {type(light).__name__}"
        )
    position = np.asarray(getattr(light, "position_mm", np.zeros(3)), np.float64)
    moved = PointLight(rig.R @ position + rig.T, light.intensity, light.falloff)
    return eqx.tree_at(lambda m: m.light, model, moved)


def synthesize(out: str | Path, options: SynthOptions = SynthOptions()) -> Path:
    """Generate a synthetic laparoscope capture into folder `out`; returns the folder.

    Writes the capture format (camera.json, images/, depth/, normals/, poses.json), the
    true albedo maps (albedo/NAME.npy: rho_tilde per pixel, (H, W, 3), NaN off the surface)
    and truth.json with `rho_tilde`, `F_tilde`, `sigma` (the paper's scaled weights, linear
    units where 1.0 is 8-bit level 255), the poses, the noise and the effects used.
    """
    # The model first: a bad parameter fails before any work. No timings in truth.json,
    # so that the same options give byte-identical captures.
    model = scene_model(options)
    rng = np.random.default_rng(options.seed)
    surface_rng, texture_rng, path_rng, noise_rng = rng.spawn(4)
    # Spawned only for sparkles: the other streams, and the default capture, stay as they were.
    sparkle_rng = rng.spawn(1)[0] if options.sparkles else None
    # Sparkles: the specular lobes are the facets' own (sharp) ones, lit on the facets.
    lit_model = scene_model(options, sigma=SPARKLE_MICRO_SIGMA) if options.sparkles else model
    surface = OrganSurface.random(surface_rng, WORKING_DISTANCE_MM)
    camera = synthetic_camera(options)
    # The tissue a pixel covers at the working distance (the prefilter's scale).
    pixel_mm = WORKING_DISTANCE_MM / float(camera.fx)
    seed = texture_rng.bit_generator.seed_seq
    texture = seeded_texture(seed, pixel_mm) if options.texture else None
    poses = exploration(options.frames, path_rng, WORKING_DISTANCE_MM)
    frames = []
    saturated = []
    true_albedo = {}
    rig = _stereo_rig(options, camera)
    right_model = None if rig is None else _seen_from_the_right(lit_model, rig)
    right_images = {}
    top = 255 if options.bits == 8 else 65535
    attached = None
    if options.sparkles_attached:
        attached = _tissue_slopes(options.sigma, options.sparkle_px, pixel_mm, sparkle_rng)

    def view(model, pose, index):
        """One camera's linear image of frame `index` at `pose`, and its geometry."""
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
        facets = None
        if attached is not None:
            slopes = [sample_field(f, points_world) for f in attached]
            facets = _tilted(normals, slopes, rotation=pose[:3, :3])
        elif sparkle_rng is not None:
            facets = _facet_normals(normals, options.sigma, options.sparkle_px, sparkle_rng)
        linear = np.asarray(_render_frame(model, camera, depth, normals, albedo_map, index, facets))
        noisy = linear + noise_rng.normal(0, options.noise_levels / 255, linear.shape)
        quantised = np.round(np.clip(noisy, 0, 1) * top) / top
        return quantised.astype(np.float32), depth, normals, albedo_map

    for index, pose in enumerate(poses):
        name = f"frame_{index:03d}"
        image, depth, normals, albedo_map = view(lit_model, pose, index)
        true_albedo[name] = np.where(
            np.isfinite(depth)[..., None],
            albedo_map * np.asarray(options.rho_tilde, np.float32),
            np.nan,
        ).astype(np.float32)
        saturated.append(float(np.mean(np.any(image >= 1, axis=-1))))
        frames.append(Frame(name, image, depth, normals, pose))
        if rig is not None:
            right_images[name] = view(right_model, pose @ rig.left_from_right(), index)[0]
    truth = {
        "rho_tilde": list(map(float, options.rho_tilde)),
        "F_tilde": list(map(float, options.F_tilde)),
        "sigma": effective_sigma(options),
        "units": "linear intensity, 1.0 = 8-bit level 255 (light intensity folded in)",
        "model": "paper eq. (1)-(2): rho_tilde/pi (N.L) + F_tilde D / (pi (N.L)(N.V)), "
        "Beckmann D = exp(-tan^2 a / sigma^2) / (sigma^2 cos^4 a)",
        "light": {
            "model": "colocated" if isinstance(model.light, ColocatedLight) else "point",
            "position_mm": named_parameters(model.light).get("offset_mm", [0.0, 0.0, 0.0]),
            "intensity": 1.0,
        },
        "effects": effects_truth(options),
        "noise_levels": float(options.noise_levels),
        "bits": options.bits,
        "texture": options.texture,
        "texture_contrast": options.texture_contrast,
        "texture_note": "textured captures multiply rho_tilde per pixel by a map of mean 1, "
        "prefiltered for the pixel footprint at the working distance (what a pixel "
        "integrates: a Gaussian of the box's spread, 0.29 pixel)",
        "albedo_maps": "albedo/NAME.npy: the true rho_tilde of every pixel, float32 (H, W, 3), "
        "NaN off the surface (the diffuse lobe's weight; effects such as a light's "
        "intensity or falloff are not folded in)",
        "seed": options.seed,
        "saturated_fraction": saturated,
        "organ": {"base_mm": surface.base_mm, "radius_mm": surface.radius_mm},
        "poses": {frame.name: frame.pose.tolist() for frame in frames},
    }
    if options.sparkles:
        truth["sparkles"] = {
            "facet_sigma": float(options.sigma),
            "micro_sigma": SPARKLE_MICRO_SIGMA,
            "correlation_px": options.sparkle_px,
            "note": "every pixel one facet, the surface's normal (normals/) tilted by a "
            "Beckmann slope of roughness facet_sigma, "
            + (
                "one field over the tissue (the same facet at a surface point in every frame)"
                if options.sparkles_attached
                else "drawn anew each frame"
            )
            + ", lit by a lobe of roughness micro_sigma; sigma is the effective roughness, "
            "hypot(facet_sigma, micro_sigma), of the lobe a pixel-averaged model sees",
            "attached": bool(options.sparkles_attached),
        }
    if rig is not None:
        truth["stereo"] = {"baseline_mm": rig.baseline_mm, "light": "at the left lens"}
    root = write_capture(
        out, camera, frames, truth, bits=options.bits, stereo=rig, right=right_images or None
    )
    for name, albedo in true_albedo.items():
        atomic_write_npy(root / "albedo" / f"{name}.npy", albedo)
    return root
