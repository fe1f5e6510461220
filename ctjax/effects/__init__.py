"""Per-pixel effects between scene radiance and the recorded pixel: ambient light, the
camera's response, and those that depend on where the value was recorded (`Site`: the
pixel and the frame): the optics' vignetting, the scope's auto-exposure."""

from ._ambient import Ambient as Ambient
from ._effect import AbstractImageEffect as AbstractImageEffect
from ._effect import Gain as Gain
from ._effect import Site as Site
from ._exposure import FrameExposure as FrameExposure
from ._gamma import CameraGamma as CameraGamma
from ._knee import Knee as Knee
from ._named import image_effect_names as image_effect_names
from ._named import image_effects as image_effects
from ._srgb import SRGBResponse as SRGBResponse
from ._vignetting import Vignetting as Vignetting
