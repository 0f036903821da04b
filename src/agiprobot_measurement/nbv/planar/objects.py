"""Test bodies: six labelled substitutes for the report's undescribed ``getmodel .. getmodel6``, and bodies from files.

All substitutes live on a 400 x 400 grid (1 cell = 1 mm), centred, and are rasterised by cell centre (a cell is body
when its centre lies inside the shape). They are *substitutes*: the report does not describe its models.

=============  ==========================================================  =================================
name           shape (cells)                                               what it exercises
=============  ==========================================================  =================================
rectangle      160 x 100, axis-aligned                                     straight contour, right corners
disc           radius 50                                                   mild curvature (strategy 0)
rotated_rect   140 x 80 rotated by 30 degrees                               staircase contour
triangle       right triangle, legs 160 and 92.4, a 30 degree acute corner  sharp angle (strategies 1 / 2)
l_shape        two 160 x 50 arms                                           concave corner, occlusion
u_shape        140 x 140 with a 20 wide, 100 deep slot                      partly unmeasurable slot (7.1)
=============  ==========================================================  =================================
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image

from agiprobot_measurement.common.limits import LIMITS, InputTooLarge, check_count
from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.grid import validate_truth

__all__ = ["OBJECT_NAMES", "load_object_file", "make_object", "polygon_mask"]

GRID_SHAPE = (400, 400)
OBJECT_NAMES = ("rectangle", "disc", "rotated_rect", "triangle", "l_shape", "u_shape")


def polygon_mask(shape, vertices) -> np.ndarray:
    """Cells whose centre is inside the polygon ``vertices`` (k x 2, cells), by the even-odd rule."""
    v = np.asarray(vertices, dtype=float)
    xs, ys = np.meshgrid(np.arange(shape[0], dtype=float), np.arange(shape[1], dtype=float), indexing="ij")
    inside = np.zeros(shape, dtype=bool)
    for k in range(len(v)):
        (x1, y1), (x2, y2) = v[k], v[(k + 1) % len(v)]
        if y1 == y2:
            continue
        crosses = (ys >= min(y1, y2)) & (ys < max(y1, y2))
        x_at = x1 + (ys - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (xs < x_at)
    return inside


def _rect(cx, cy, w, h, angle_rad=0.0):
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    pts = np.array([(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)])
    return pts @ np.array([[c, s], [-s, c]]) + (cx, cy)


def make_object(name: str) -> np.ndarray:
    """The ground truth of a named substitute body: FULL (1) body, EMPTY (-1) elsewhere, 400 x 400."""
    cx, cy = (GRID_SHAPE[0] - 1) / 2, (GRID_SHAPE[1] - 1) / 2
    if name == "rectangle":
        mask = polygon_mask(GRID_SHAPE, _rect(cx, cy, 160, 100))
    elif name == "disc":
        xs, ys = np.meshgrid(np.arange(GRID_SHAPE[0]), np.arange(GRID_SHAPE[1]), indexing="ij")
        mask = (xs - cx) ** 2 + (ys - cy) ** 2 <= 50.0**2
    elif name == "rotated_rect":
        mask = polygon_mask(GRID_SHAPE, _rect(cx, cy, 140, 80, math.radians(30)))
    elif name == "triangle":
        leg = 160.0
        height = leg * math.tan(math.radians(30))
        x0, y0 = cx - leg / 2, cy - height / 2
        mask = polygon_mask(GRID_SHAPE, [(x0, y0), (x0 + leg, y0), (x0, y0 + height)])
    elif name == "l_shape":
        x0, y0 = cx - 80, cy - 80
        mask = polygon_mask(GRID_SHAPE, [(x0, y0), (x0 + 160, y0), (x0 + 160, y0 + 50), (x0 + 50, y0 + 50),
                                         (x0 + 50, y0 + 160), (x0, y0 + 160)])  # fmt: skip
    elif name == "u_shape":
        x0, y0 = cx - 70, cy - 70
        mask = polygon_mask(GRID_SHAPE, [(x0, y0), (x0 + 140, y0), (x0 + 140, y0 + 140), (x0 + 80, y0 + 140),
                                         (x0 + 80, y0 + 40), (x0 + 60, y0 + 40), (x0 + 60, y0 + 140),
                                         (x0, y0 + 140)])  # fmt: skip
    else:
        raise NbvInputError(f"unknown object {name!r}; choose one of {', '.join(OBJECT_NAMES)}")
    return validate_truth(mask, name)


def _npy_shape(path: Path) -> tuple[int, ...]:
    """The array shape a ``.npy`` file's header declares (nothing of the data is read)."""
    with path.open("rb") as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, _, _ = np.lib.format.read_array_header_1_0(f)
        else:
            shape, _, _ = np.lib.format.read_array_header_2_0(f)
    return tuple(int(n) for n in shape)


def _check_pixels(shape: tuple[int, ...], path: Path) -> None:
    """:class:`InputTooLarge` when an image or mask of ``shape`` has more cells than ``LIMITS.image_pixels``."""
    check_count(math.prod(shape), LIMITS.image_pixels, f"{path}: cells of the object ({' x '.join(map(str, shape))})")


def load_object_file(path: Path | str) -> np.ndarray:
    """A body from a ``.npy`` mask (indexed ``[i, j]`` like the model; > 0 is body) or an image.

    Images are read as pictures: row 0 is the top, dark pixels (below half the intensity range) are body, and the
    picture's x / y become the grid's i / j. The body must not touch the border.
    """
    p = Path(path)
    if not p.is_file():
        raise NbvInputError(f"object file not found: {p}")
    if p.suffix.lower() == ".npy":
        try:
            _check_pixels(_npy_shape(p), p)
            arr = np.load(p, allow_pickle=False)
        except InputTooLarge:
            raise
        except (OSError, ValueError, MemoryError) as exc:
            raise NbvInputError(f"cannot read the mask {p}: {exc}") from exc
        if arr.dtype != bool and not np.issubdtype(arr.dtype, np.number):
            raise NbvInputError(f"{p}: a mask must be boolean or numeric, got {arr.dtype}")
        return validate_truth(arr, str(p))
    try:
        with Image.open(p) as header:  # reads the header only: the size is checked before decoding
            width, height = header.size
            _check_pixels((height, width), p)
            if header.mode in ("1", "L", "I", "F") or header.mode.startswith("I;"):
                img = np.asarray(header, dtype=np.float32)
            else:  # colour, palette, with alpha: the mean of red, green and blue
                img = np.asarray(header.convert("RGB"), dtype=np.float32).mean(axis=2)
    except InputTooLarge:
        raise
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise NbvInputError(f"cannot read the image {p}: {exc}") from exc
    if img.ndim != 2 or img.size == 0:
        raise NbvInputError(f"{p}: not a 2D image")
    lo, hi = float(img.min()), float(img.max())
    if hi <= lo:
        raise NbvInputError(f"{p}: the image is uniform; no body can be told from the background")
    body = img < (lo + hi) / 2
    return validate_truth(np.flipud(body).T, str(p))
