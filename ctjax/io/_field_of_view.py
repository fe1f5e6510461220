"""The endoscope's field of view: what in a frame is the scene, and what is not.

An endoscope's image is a circle or a polygon (an octagon on some colonoscopes) inside a
black border, and videos carry overlays: a logo, an icon, text, a timestamp, constant over
the video. Neither is tissue: no pixel of them may reach the masks, the fits or the
structure-from-motion features.

- **Border** (`field_of_view`): the dark pixels (brightest channel at most `border_level`)
  connected to the image's edge, after a morphological opening that keeps only regions at
  least `border_px` wide (a dark vessel or a shadow touching the edge is not a border), with
  their holes filled; the field of view is the rest, less the lens's edge, shrunk by
  `margin_px` (where vignetting and the lens's edge blur the values). The lens's edge
  (`_without_rim`): within `RIM_BAND` of the border, the dim pixels (brightest channel at
  most twice `border_level`) and the near-white ones (every channel at least `RIM_WHITE`)
  reached from the border through each other, where they hold a ring (`RIM_RING`). On a
  sinus scope's frames (the shared sequence, 640 px wide) that is a halo of 12-18 levels
  just above `border_level`, a black line and a white ring (238-241 of 255) up to 10 px
  inside the dark border: not the scene, yet its ring counted as near-white cores and its
  halo as dark tissue. Without a ring (a laparoscope's circle) dark tissue by the border
  stays.
- **Overlays** (`overlay_mask`): pixels constant over the frames of a video (every channel
  within a range of 2 `tolerance`) while the scene moves under them; at least
  `MIN_OVERLAY_FRAMES` (8) frames, and only where the scene changes (a still camera shows
  nothing); solid regions only (an opening removes tissue pixels that stay within the
  tolerance by chance), and not a clipped highlight's core, which can stay put while the
  camera moves (its surroundings stay whitish in every frame; a UI element's are tissue).
  In a few frames, or one (`white_overlays`): blobs of at least `MIN_OVERLAY_PX` pixels
  (at 1080p, scaled to the image's area; at least `MIN_OVERLAY_PX_ANY`) and at most
  `MAX_OVERLAY_SHARE` of the image (a larger white region is over-exposed scene) whose every
  channel is at the top (`OVERLAY_WHITE`) in every frame, and whose surroundings 2 px out
  have the local tissue's colour in every frame: a drawn icon or text has a sharp edge
  onto the tissue, a clipped highlight's core fades into a halo whiter than the tissue
  (`OVERLAY_EDGE_WHITENING`), and moves when the camera does. Limit: in a single frame, a
  glint of more than 30 px whose edge is as sharp as a drawn one is taken as an overlay.

A synthetic or cropped capture has no border and no overlay: everything is in view.

- **Nothing in view** (`black_frames`): why a capture cannot be measured, where frames have no
  pixel in their field of view (black, or all border: named) or all are saturated.
"""

import cv2
import numpy as np

from .._errors import ParameterError
from .._threads import default_workers, in_order
from .._tissue import channel_max, channel_min, local_tissue

# The border's brightest channel is at most this (recorded values in [0, 1]): 15 of 255.
DEFAULT_BORDER_LEVEL = 0.06
# A border region is at least this wide (px), at 1080p scaled to the image's width.
DEFAULT_BORDER_PX = 9
# The field of view is shrunk by this much (px) from the border, at 1080p scaled to the
# image's width (at least 1 px).
DEFAULT_MARGIN_PX = 3
# The lens's edge is looked for within this fraction of the image's width of the border ...
RIM_BAND = 0.025
# ... its bright ring: every channel at least this (the ring is near-white, the tissue
# beside it is not) ...
RIM_WHITE = 0.85
# ... at least this fraction of the image's width in near-white pixels (a ring along the
# border, not a sparkle beside it; without a ring, the dim pixels stay: dark tissue).
RIM_RING = 0.05
# An overlay pixel stays within this of its median value in every frame (2 of 255).
DEFAULT_OVERLAY_TOLERANCE = 2 / 255
# A constant blob whose surroundings' least channel stays at least this bright in every
# frame is a clipped highlight's core, not an overlay.
HIGHLIGHT_SURROUND = 0.5
# Overlays are looked for in videos of at least this many frames: in a few frames a clipped
# highlight can stay put, and texture can stay within the tolerance, by chance.
MIN_OVERLAY_FRAMES = 8
# A single frame's white overlay: every channel at least this (the top 3 of 255 levels).
OVERLAY_WHITE = 252 / 255
# ... a blob of at least this many pixels at 1920 px wide (scaled to the image's area, and
# at least MIN_OVERLAY_PX_ANY: an icon or a glyph is drawn to be read) ...
MIN_OVERLAY_PX = 40
MIN_OVERLAY_PX_ANY = 30
# ... and of at most this share of the image: drawn to be read beside the scene, not over
# it (a white region larger than that is the scene, over-exposed: clipped, not overlaid) ...
MAX_OVERLAY_SHARE = 0.05
# ... whose surroundings 2 px out are tissue: on average at most this far from the local
# tissue's colour towards white (a highlight's halo is whiter than the tissue) ...
OVERLAY_EDGE_WHITENING = 0.25
# ... the local tissue's colour: a median over this fraction of the image's width.
OVERLAY_WINDOW = 1 / 12


def _check_image(image: np.ndarray) -> None:
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ParameterError(f"image must be (H, W, 3) RGB, got shape {image.shape}")


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def field_of_view(
    image: np.ndarray,
    *,
    border_level: float = DEFAULT_BORDER_LEVEL,
    border_px: int = DEFAULT_BORDER_PX,
    margin_px: int = DEFAULT_MARGIN_PX,
) -> np.ndarray:
    """(H, W) bool, True inside the endoscope's field of view (see the module doc)."""
    _check_image(image)
    if not 0 <= border_level < 1:
        raise ParameterError(f"border_level must be in [0, 1), got {border_level}")
    dark = (channel_max(image) <= border_level).astype(np.uint8)
    height, width = dark.shape
    if not dark.any():
        return np.ones((height, width), bool)
    # Only regions at least `border_px` wide: opening removes thinner dark structures.
    radius = max(1, round(border_px * width / 1920 / 2))
    dark = cv2.morphologyEx(dark, cv2.MORPH_OPEN, _disk(radius))
    count, labels = cv2.connectedComponents(dark, connectivity=8)
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    border = np.isin(labels, edge[edge > 0])
    if not border.any():
        return np.ones((height, width), bool)
    # The scene: the largest region that is not border (its holes, dark tissue, kept).
    count, labels, stats, _ = cv2.connectedComponentsWithStats((~border).astype(np.uint8), 4)
    if count <= 1:
        return np.zeros((height, width), bool)
    scene = labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    scene = _without_rim(image, scene, border_level)
    margin = round(margin_px * width / 1920)
    if margin_px > 0:
        scene = cv2.erode(scene.astype(np.uint8), _disk(max(1, margin))).astype(bool)
    return scene


def _without_rim(image: np.ndarray, scene: np.ndarray, border_level: float) -> np.ndarray:
    """`scene` less the lens's edge (see the module doc): the dim and the near-white pixels
    within `RIM_BAND` of the border that a path through such pixels joins to it, where
    they hold a ring (`RIM_RING`). Tissue stops the path, so a highlight beyond the first
    tissue pixel stays in view; the image's own edge is no border (a cropped frame loses
    nothing there); a scope without a ring loses nothing."""
    inside = cv2.distanceTransform(scene.astype(np.uint8), cv2.DIST_L2, 3)
    band = scene & (inside <= max(2, round(RIM_BAND * scene.shape[1])))
    edge_like = band & (
        (channel_max(image) <= 2 * border_level) | (channel_min(image) >= RIM_WHITE)
    )
    if not edge_like.any():
        return scene
    count, labels = cv2.connectedComponents(edge_like.astype(np.uint8), connectivity=8)
    touching = np.zeros(count, bool)
    touching[labels[edge_like & (inside <= 1.5)]] = True
    # A ring, not a sparkle: at least RIM_RING of the width in near-white pixels.
    white = np.bincount(labels[channel_min(image) >= RIM_WHITE], minlength=count)
    edge = touching & (white >= RIM_RING * scene.shape[1])
    edge[0] = False
    return scene & ~edge[labels]


def overlay_mask(
    images: list[np.ndarray], *, tolerance: float = DEFAULT_OVERLAY_TOLERANCE
) -> np.ndarray:
    """(H, W) bool, True on overlays: pixels whose every channel stays within a range of
    2 `tolerance` over `images` (frames of one video) while the scene changes. All False
    with fewer than `MIN_OVERLAY_FRAMES` frames or where nothing changes (see the module
    doc). Dilated by 2 px (an overlay's anti-aliased edge)."""
    if len(images) < MIN_OVERLAY_FRAMES:
        return np.zeros(images[0].shape[:2], bool) if images else np.zeros((0, 0), bool)
    low = high = None
    for image in images:  # running extremes: memory of two frames, however long the video
        _check_image(image)
        low = image.copy() if low is None else np.minimum(low, image)
        high = image.copy() if high is None else np.maximum(high, image)
    constant = np.all(high - low <= 2 * tolerance, axis=-1)
    dark = np.max(high, axis=-1) <= DEFAULT_BORDER_LEVEL
    constant &= ~dark  # the black border is the field of view's business
    changing = ~constant & ~dark
    if not changing.any() or constant.mean() > 0.5:
        # A still camera (or an unchanging scene): nothing tells an overlay from tissue.
        return np.zeros(constant.shape, bool)
    # Overlays are solid (an icon, text strokes); tissue that happens to stay within the
    # tolerance in every frame is scattered pixels, which an opening removes.
    solid = cv2.morphologyEx(constant.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    overlay = np.zeros(constant.shape, bool)
    count, labels = cv2.connectedComponents(solid, connectivity=8)
    whiteness = np.min(low, axis=-1)  # the least white each pixel ever was
    for label in range(1, count):
        blob = labels == label
        around = cv2.dilate(blob.astype(np.uint8), _disk(3)).astype(bool) & ~blob
        # A clipped highlight's core can stay put while the camera moves; it is not an
        # overlay: its surroundings stay whitish in every frame, a UI element's are tissue.
        if around.any() and np.median(whiteness[around]) >= HIGHLIGHT_SURROUND:
            continue
        overlay |= blob
    return cv2.dilate(overlay.astype(np.uint8), _disk(2)).astype(bool)


def white_overlays(images: list[np.ndarray]) -> np.ndarray:
    """(H, W) bool, True on white overlays (see the module doc): white in every frame of
    `images` (one frame will do), with a sharp edge onto tissue in every frame. Dilated by
    2 px (their anti-aliased edge)."""
    for image in images:
        _check_image(image)
    white = np.ones(images[0].shape[:2], bool)
    for image in images:
        white &= channel_min(image) >= OVERLAY_WHITE
    if not white.any():
        return np.zeros(white.shape, bool)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(white.astype(np.uint8), 8)
    width = white.shape[1]
    smallest = max(MIN_OVERLAY_PX_ANY, MIN_OVERLAY_PX * (width / 1920) ** 2)
    area = stats[:, cv2.CC_STAT_AREA]
    sharp = (area >= smallest) & (area <= MAX_OVERLAY_SHARE * white.size)
    sharp[0] = False
    if not sharp.any():
        return np.zeros(white.shape, bool)
    # The band 2 px outside each blob, labelled by the blob it surrounds.
    grown = cv2.dilate(labels.astype(np.float32), _disk(2))
    band = (labels == 0) & (grown > 0) & ~cv2.dilate(white.astype(np.uint8), _disk(1)).astype(bool)
    owner = grown[band].astype(np.int64)
    pixels = np.maximum(np.bincount(owner, minlength=count), 1)
    # The frames on threads (OpenCV and NumPy release the GIL).
    whitened = in_order(lambda image: _whitening(image, white, band), images, default_workers())
    for whitening in whitened:
        sharp &= np.bincount(owner, whitening, count) / pixels <= OVERLAY_EDGE_WHITENING
    return cv2.dilate(sharp[labels].astype(np.uint8), _disk(2)).astype(bool)


def _whitening(image: np.ndarray, white: np.ndarray, band: np.ndarray) -> np.ndarray:
    """How far each `band` pixel has moved from the local tissue's colour towards white
    (0: tissue, 1: white)."""
    tissue = local_tissue(image, ~white, OVERLAY_WINDOW)[band]
    tissue_ratio = np.minimum(channel_min(tissue) / np.maximum(channel_max(tissue), 1e-6), 0.95)
    ratio = channel_min(image[band]) / np.maximum(channel_max(image[band]), 1e-6)
    return np.clip((ratio - tissue_ratio) / (1 - tissue_ratio), 0, 1)


def visible_masks(images: list[np.ndarray]) -> list[np.ndarray]:
    """Every frame's pixels of the scene: inside the field of view and off the overlays
    (those constant over the frames, and white ones with sharp edges in each frame)."""
    overlay = overlay_mask(images) | white_overlays(images)
    return [field_of_view(image) & ~overlay for image in images]


# A capture whose frames are white (every channel at full scale) over at least this share
# of their view on average is saturated: nothing to measure.
SATURATED_SHARE = 0.95


def black_frames(capture) -> str | None:
    """Why no frame has a pixel of the scene, where none has one in its field of view (black
    images, or all border), or where the frames are white over `SATURATED_SHARE` of their
    view (saturated); None otherwise."""
    if not capture.frames:
        return None

    def white(frame) -> float:
        white = channel_min(frame.image) >= 254.5 / 255
        if frame.field_of_view is None or not frame.field_of_view.any():
            return float(np.mean(white))
        return float(np.mean(white[frame.field_of_view]))

    share = float(np.mean([white(f) for f in capture.frames]))
    if share >= SATURATED_SHARE:  # a flat field at full scale is no scene (and not black)
        return (
            f"{capture.root}: the images are saturated ({share:.0%} of the pixels white, "
            "every channel at full scale): lower the exposure or the light"
        )
    # A frame without a field-of-view mask shows the whole image.
    empty = [f for f in capture.frames if f.field_of_view is not None and not f.field_of_view.any()]
    if not empty:
        return None
    brightest = max(float(np.max(frame.image)) for frame in empty)
    if len(empty) < len(capture.frames):
        names = ", ".join(f.name for f in empty[:5]) + (" ..." if len(empty) > 5 else "")
        return (
            f"{capture.root}: frame(s) {names} have no pixel in their field of view (black: "
            f"brightest level {brightest:.3g} of 1, all border, or excluded): remove them from the "
            "capture"
        )
    if brightest < _BLACK_LEVEL:
        why = f"the images are black (their brightest level {brightest:.3g} of 1)"
    else:  # bright images whose every pixel was masked: not black
        why = (
            f"the images are not black (brightest level {brightest:.3g} of 1) but every pixel "
            "is border, overlay or excluded, or camera.json's distortion moved the image out of "
            "its frame"
        )
    return f"{capture.root}: no frame has a pixel in its field of view: {why}"


# Brighter than this (linear, of 1) anywhere, a frame is not black.
_BLACK_LEVEL = 0.1
