"""The laparoscope's light in the camera frame, and its falloff with position."""

from ._field import LightField as LightField
from ._field import angles_from_direction as angles_from_direction
from ._field import direction_from_angles as direction_from_angles
from ._guides import LightGuides as LightGuides
from ._inverse_square import InverseSquare as InverseSquare
from ._lens_plane import LensPlaneLight as LensPlaneLight
from ._light import AbstractFalloff as AbstractFalloff
from ._light import AbstractLight as AbstractLight
from ._point import ColocatedLight as ColocatedLight
from ._point import PointLight as PointLight
from ._spot import SpotFalloff as SpotFalloff
