"""Light calibration: the laparoscope's light from images (paper section 5, and beyond)."""

from ._light_field import LightFieldCalibration as LightFieldCalibration
from ._light_field import calibrate_light_field as calibrate_light_field
from ._near_light import NearLightCalibration as NearLightCalibration
from ._near_light import calibrate_near_light as calibrate_near_light
