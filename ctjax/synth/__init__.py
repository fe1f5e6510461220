"""Synthetic laparoscope captures with known truth, and real-like endoscopic frames."""

from ._real_like import RealLikeFrame as RealLikeFrame
from ._real_like import real_like_frame as real_like_frame
from ._synthesize import SPARKLE_MICRO_SIGMA as SPARKLE_MICRO_SIGMA
from ._synthesize import SynthOptions as SynthOptions
from ._synthesize import effective_sigma as effective_sigma
from ._synthesize import effects_truth as effects_truth
from ._synthesize import scene_model as scene_model
from ._synthesize import synth_effects as synth_effects
from ._synthesize import synthesize as synthesize
from ._synthesize import synthetic_camera as synthetic_camera
