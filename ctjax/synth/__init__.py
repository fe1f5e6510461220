"""Synthetic laparoscope captures with known truth."""

from ._synthesize import SynthOptions as SynthOptions
from ._synthesize import scene_model as scene_model
from ._synthesize import synthesize as synthesize
from ._synthesize import synthetic_camera as synthetic_camera
