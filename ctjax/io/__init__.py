"""Files at the edges: the capture format, images."""

from ._alta import MeasuredBRDF as MeasuredBRDF
from ._alta import load_alta as load_alta
from ._camera_json import read_camera as read_camera
from ._capture import Capture as Capture
from ._capture import Frame as Frame
from ._capture import load_capture as load_capture
from ._capture import write_capture as write_capture
from ._field_of_view import field_of_view as field_of_view
from ._field_of_view import overlay_mask as overlay_mask
from ._field_of_view import visible_masks as visible_masks
from ._field_of_view import white_overlays as white_overlays
from ._images import read_rgb as read_rgb
from ._images import write_rgb as write_rgb
from ._opencv_calibration import camera_json_from_opencv as camera_json_from_opencv
from ._registered import registered_frames as registered_frames
from ._video import ImportOptions as ImportOptions
from ._video import import_video as import_video
