"""The shading model: everything between the scene's geometry and a pixel value."""

import equinox as eqx

from ._convert import strongly_typed
from ._render import render, shade, shade_columns
from ._typing import RGB
from ._vector import Vec3
from .effects import AbstractImageEffect
from .lights import AbstractLight, ColocatedLight
from .lobes import BRDF, cook_torrance_brdf


class ShadingModel(eqx.Module):
    """Everything between the scene's geometry and a pixel value: BRDF, light, effects."""

    brdf: BRDF
    light: AbstractLight
    effects: tuple[AbstractImageEffect, ...] = ()

    def __call__(self, point: Vec3, normal: Vec3, pixel, frame=0, eye=None) -> RGB:
        """The predicted RGB of one pixel of capture frame `frame` (the renderer's `shade`;
        `eye`: a viewer away from the light's lens, e.g. a stereo scope's right camera)."""
        return shade(self.brdf, self.light, point, normal, pixel, self.effects, frame, eye)

    def render(self, camera, normals, depth, frame: int = 0):
        """The model's image of a surface, as frame `frame` of its capture (see
        `ctjax.render`): (H, W, 3)."""
        return render(
            self.brdf, self.light, camera, normals, depth, effects=self.effects, frame=frame
        )

    def columns(self, point: Vec3, normal: Vec3, pixel, eye=None):
        """Per-lobe radiance for unit weights (no effects): the linear design row."""
        return shade_columns(self.brdf, self.light, point, normal, pixel, eye)


def paper_model(rho_tilde=1.0, F_tilde=0.3, sigma=0.2) -> ShadingModel:
    """The paper's model: Lambertian + Beckmann specular, constant F, light at the camera.

    Its arrays are strongly typed (see `strongly_typed`), like the fitters' copies of it.
    """
    model = ShadingModel(cook_torrance_brdf(rho_tilde, F_tilde, sigma), ColocatedLight())
    return strongly_typed(model)
