"""Light calibration: the laparoscope's light from images (paper section 5, and beyond)."""

from ._near_light import NearLightCalibration as NearLightCalibration
from ._near_light import calibrate_near_light as calibrate_near_light
