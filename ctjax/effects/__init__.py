"""Per-pixel effects between scene radiance and the recorded pixel (ambient, camera response)."""

from ._ambient import Ambient as Ambient
from ._effect import AbstractImageEffect as AbstractImageEffect
from ._gamma import CameraGamma as CameraGamma
from ._srgb import SRGBResponse as SRGBResponse
