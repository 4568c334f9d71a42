"""Load ROS ``map_server`` occupancy maps (a YAML file plus a PGM/PNG image) into a :class:`Map`.

The pixel rules reproduce ``nav2_map_server/src/map_io.cpp`` (``loadMapYaml`` and
``loadMapFromFile``), which reads the image with GraphicsMagick built with 16-bit quanta (``MaxRGB``
= 65535, as on Ubuntu/ROS). For every pixel:

* ``shade`` = mean of the red, green and blue quanta / 65535 (grey images have R = G = B, so a grey
  8-bit pixel ``v`` gives ``shade = v / 255``; colour pixels are averaged, not luminance-weighted).
  In **trinary** mode only, if the image has an alpha channel, the alpha (65535 = opaque) is averaged
  in as a fourth channel: a transparent pixel looks darker, i.e. more occupied.
* ``p = shade`` when ``negate`` is set, else ``p = 1 - shade`` (for grey 8-bit, ``p = (255 - v)/255``).
* **trinary** (default): occupied (100) if ``p > occupied_thresh``, free (0) if
  ``p < free_thresh``, otherwise unknown (-1).
* **scale**: unknown (-1) if the pixel is not fully opaque (any alpha below the maximum, not only
  fully transparent); else occupied (100) if ``p > occupied_thresh``, free (0) if
  ``p < free_thresh``, else the cost ``rint((p - free) / (occupied - free) * 100)`` (0..100, rounding
  half to even, so values just above ``free_thresh`` give 0 and count as free).
* **raw**: the value is ``round(shade * 255)`` (half away from zero; the pixel value of an 8-bit
  image) if it lies in 0..100, else unknown (-1). ``negate``, the thresholds and alpha are ignored.

The ROS cell values are then reduced to this project's boolean grid: 100 is occupied, 0 is free, -1
is unknown, and the intermediate costs 1..99 (scale and raw modes only) are treated as
**unknown-like**: they are in ``OccupancyGrid.unknown`` and follow the ``unknown`` policy
("occupied" by default, or "free"). ``meta['cells']`` counts them separately as ``intermediate``
(they are included in ``unknown``). :func:`map_server_values` returns the exact ROS values.

Image row 0 is the top of the map (largest y); the grid is flipped so that grid row 0 is the lowest
row. ``origin`` [x, y, yaw] is the world pose of the lower-left corner of the lower-left pixel and
the grid is rotated by ``yaw`` about that corner (``OccupancyGrid.origin``).

Differences from map_server, all on the strict side: unknown top-level keys, non-finite numbers,
thresholds outside [0, 1], ``free_thresh > occupied_thresh`` (or equal thresholds in scale mode,
where map_server divides by zero), ``negate`` other than 0/1/true/false and a non-string ``image``
are errors. As in yaml-cpp, numbers may be written as strings ("0.05") or in exponent form without a
dot (5e-2, which PyYAML's YAML 1.1 resolver leaves as a string).
"""

from __future__ import annotations

import io
import math
import re
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image as _PILImage

from ..errors import InputError
from ..limits import MAX_CELL_M, MAX_COORD_M, MAX_GRID_CELLS, MIN_CELL_M
from ..safe_io import read_bytes, read_yaml_mapping
from .base import Map, MapError, OccupancyGrid

__all__ = [
    "ALLOWED_KEYS",
    "MODES",
    "RasterImage",
    "RosMapParams",
    "load_ros_map",
    "map_server_values",
    "read_image",
    "read_map_yaml",
]

ALLOWED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode")
REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")
MODES = ("trinary", "scale", "raw")
UNKNOWN_POLICIES = ("occupied", "free")

OCC_GRID_FREE = 0
OCC_GRID_OCCUPIED = 100
OCC_GRID_UNKNOWN = -1
QUANTUM_MAX = 65535.0          # GraphicsMagick Q16 MaxRGB

_FLOAT_TEXT = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_NETPBM_WHITESPACE = b" \t\n\r\v\f"
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_NETPBM_NUMBER = re.compile(rb"\d{1,9}(?=[ \t\n\r\v\f#]|$)")   # a header field: digits, then a separator


@dataclass(frozen=True)
class RosMapParams:
    """The validated contents of a map_server YAML file."""

    yaml_path: Path
    image: Path                                  # resolved: absolute, or relative to the YAML's folder
    resolution: float                            # m per pixel, > 0
    origin: tuple[float, float, float]           # pose of the lower-left pixel corner (x, y, yaw)
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: str = "trinary"                        # one of MODES


@dataclass(frozen=True)
class RasterImage:
    """Pixels as GraphicsMagick Q16 quanta (0..65535), image row 0 at the top.

    ``colour`` is (H, W) for grey images (R = G = B) or (H, W, 3) for colour images; ``alpha`` is
    (H, W) with 65535 = opaque, or None when the image has no alpha channel (GraphicsMagick
    ``matte() == false``).
    """

    colour: np.ndarray
    alpha: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.colour.shape[:2]


# --------------------------------------------------------------------------------------------------
# Public API


def load_ros_map(path, unknown: str = "occupied") -> Map:
    """Load a ROS map_server map (YAML + PGM/PNG image) as a :class:`Map` with one occupancy grid.

    ``unknown`` decides how cells that are neither free nor occupied in the source (ROS value -1,
    and in scale/raw modes the intermediate costs 1..99) count in ``OccupancyGrid.occupied``:
    ``"occupied"`` (default, conservative) or ``"free"``. They are always marked in
    ``OccupancyGrid.unknown``.

    The returned map has ``name`` = the YAML file stem, ``grids = (grid,)``, ``bounds`` = the grid's
    world bounds, ``source`` = ``str(path)`` and ``meta`` with the YAML parameters, the unknown
    policy and ``cells`` = counts of occupied / free / unknown (including intermediate) /
    intermediate cells as read from the source, before the policy is applied.

    Raises :class:`MapError` (naming the file) for a missing or malformed YAML file or image, and
    :class:`InputError` (argument ``unknown``) for an unknown policy.
    """
    if not isinstance(unknown, str) or unknown not in UNKNOWN_POLICIES:
        raise InputError("unknown", "'occupied' or 'free' (how unknown cells count)", unknown)
    params = read_map_yaml(path)
    image = read_image(params.image, referenced_by=params.yaml_path)
    values = map_server_values(image, params.mode, params.negate, params.occupied_thresh, params.free_thresh)

    occupied_src = values == OCC_GRID_OCCUPIED
    free_src = values == OCC_GRID_FREE
    unknown_mask = ~(occupied_src | free_src)
    intermediate = unknown_mask & (values != OCC_GRID_UNKNOWN)
    occupied = occupied_src | unknown_mask if unknown == "occupied" else occupied_src
    try:
        grid = OccupancyGrid(occupied, params.resolution, params.origin, unknown=unknown_mask)
    except MapError:
        raise
    except InputError as exc:               # the grid's extent beyond nhstab.limits
        raise MapError(f"{path}: {exc.argument}", exc.expected, exc.got, detail=exc.detail) from None
    height, width = values.shape
    meta = {
        "format": "ros_map_server",
        "yaml": str(params.yaml_path),
        "image": str(params.image),
        "width": int(width),
        "height": int(height),
        "resolution": params.resolution,
        "origin": list(params.origin),
        "negate": params.negate,
        "occupied_thresh": params.occupied_thresh,
        "free_thresh": params.free_thresh,
        "mode": params.mode,
        "unknown_policy": unknown,
        "cells": {
            "occupied": int(occupied_src.sum()),
            "free": int(free_src.sum()),
            "unknown": int(unknown_mask.sum()),
            "intermediate": int(intermediate.sum()),
        },
    }
    return Map(name=Path(path).stem, bounds=grid.bounds(), grids=(grid,), source=str(path), meta=meta)


def map_server_values(image: RasterImage, mode: str = "trinary", negate: bool = False,
                      occupied_thresh: float = 0.65, free_thresh: float = 0.25) -> np.ndarray:
    """The ``nav_msgs/OccupancyGrid`` data nav2's map_server publishes for ``image``, as (H, W) int8.

    Values are -1 (unknown), 0 (free), 100 (occupied) and, in scale and raw modes, costs 1..99.
    Row 0 is the *lowest* row (map_server writes image row y to data row ``height - y - 1``).
    """
    if mode not in MODES:
        raise InputError("mode", f"one of {MODES}", mode)
    if not 0.0 <= free_thresh <= occupied_thresh <= 1.0 or (mode == "scale" and free_thresh == occupied_thresh):
        raise InputError("free_thresh, occupied_thresh", "0 <= free_thresh <= occupied_thresh <= 1 "
                         "(strictly smaller in scale mode)", (free_thresh, occupied_thresh))
    colour = np.asarray(image.colour, dtype=np.float64)
    alpha = None if image.alpha is None else np.asarray(image.alpha, dtype=np.float64)
    # Sum of the red, green and blue quanta (grey: R = G = B, so 3 * grey), as map_server does.
    total = 3.0 * colour if colour.ndim == 2 else colour[..., 0] + colour[..., 1] + colour[..., 2]
    count = 3.0
    if mode == "trinary" and alpha is not None:
        total = total + alpha              # map_server pushes MaxRGB - opacity, i.e. the alpha
        count = 4.0
    shade = (total / count) / QUANTUM_MAX
    occ = shade if negate else 1.0 - shade

    values = np.full(shade.shape, OCC_GRID_UNKNOWN, dtype=np.int8)
    if mode == "trinary":
        values[occ < free_thresh] = OCC_GRID_FREE
        values[occupied_thresh < occ] = OCC_GRID_OCCUPIED
    elif mode == "scale":
        opaque = np.ones(shade.shape, dtype=bool) if alpha is None else alpha == QUANTUM_MAX
        occupied = opaque & (occupied_thresh < occ)
        free = opaque & ~occupied & (occ < free_thresh)
        between = opaque & ~occupied & ~free
        if np.any(between):
            span = occupied_thresh - free_thresh   # > 0: equal thresholds are rejected for scale
            values[between] = np.rint((occ[between] - free_thresh) / span * 100.0).astype(np.int8)
        values[free] = OCC_GRID_FREE
        values[occupied] = OCC_GRID_OCCUPIED
    else:  # raw
        percent = np.floor(shade * 255.0 + 0.5)   # std::round, shade >= 0
        inside = (percent >= OCC_GRID_FREE) & (percent <= OCC_GRID_OCCUPIED)
        values[inside] = percent[inside].astype(np.int8)
    return np.ascontiguousarray(np.flipud(values))


def read_map_yaml(path) -> RosMapParams:
    """Read and validate a map_server YAML file (strict: only the map_server keys), with nhstab's
    safe YAML loader (:mod:`nhstab.safe_io`)."""
    path = Path(path)
    doc = read_yaml_mapping(path, what="map YAML file", keys=ALLOWED_KEYS, required=REQUIRED_KEYS, error=MapError)

    image = doc["image"]
    if not isinstance(image, str) or not image.strip():
        raise MapError(f"{path}:image", "a non-empty image file name", image)
    image_path = Path(image)
    if not image_path.is_absolute():
        image_path = path.parent / image_path

    resolution = _number(path, "resolution", doc["resolution"])

    if not MIN_CELL_M <= resolution <= MAX_CELL_M:
        raise MapError(f"{path}:resolution", f"a number of metres per pixel in [{MIN_CELL_M:g}, {MAX_CELL_M:g}]",
                       doc["resolution"])

    origin = doc["origin"]
    if not isinstance(origin, (list, tuple)) or len(origin) != 3:
        raise MapError(f"{path}:origin", "a list [x, y, yaw] of 3 numbers", origin)
    origin_values = tuple(_number(path, "origin", v) for v in origin)
    if max(abs(origin_values[0]), abs(origin_values[1])) > MAX_COORD_M:
        raise MapError(f"{path}:origin", f"a position within +-{MAX_COORD_M:g} m", origin)

    negate = doc["negate"]
    if isinstance(negate, bool):
        negate_value = negate
    elif isinstance(negate, int) and negate in (0, 1):
        negate_value = bool(negate)
    else:
        raise MapError(f"{path}:negate", "0, 1, true or false", negate)

    occupied_thresh = _number(path, "occupied_thresh", doc["occupied_thresh"])
    free_thresh = _number(path, "free_thresh", doc["free_thresh"])
    for key, value in (("occupied_thresh", occupied_thresh), ("free_thresh", free_thresh)):
        if not 0.0 <= value <= 1.0:
            raise MapError(f"{path}:{key}", "a number in [0, 1]", doc[key])
    if free_thresh > occupied_thresh:
        raise MapError(f"{path}:free_thresh", "at most occupied_thresh", free_thresh,
                       detail=f"occupied_thresh is {occupied_thresh}")

    mode = doc.get("mode", "trinary")
    if not isinstance(mode, str) or mode.lower() not in MODES:
        raise MapError(f"{path}:mode", f"one of {', '.join(MODES)}", mode)
    mode = mode.lower()
    if mode == "scale" and not free_thresh < occupied_thresh:
        raise MapError(f"{path}:free_thresh", "smaller than occupied_thresh in scale mode", free_thresh,
                       detail="map_server divides by occupied_thresh - free_thresh")
    return RosMapParams(path, image_path, resolution, origin_values, negate_value, occupied_thresh, free_thresh, mode)


def read_image(path, referenced_by=None) -> RasterImage:
    """Read a map image: PGM/PPM (P2, P5, P3, P6; 8- or 16-bit) with the built-in reader, PNG and
    other formats with Pillow.

    Truncated, corrupt or unsupported images raise :class:`MapError` naming the file.
    """
    path = Path(path)
    try:
        data = read_bytes(path, what="image file", error=_image_problem)
        if data[:2] in (b"P2", b"P5", b"P3", b"P6"):
            return _read_netpbm(data)
        if data[:2] in (b"P1", b"P4", b"P7"):
            raise _ImageProblem("a PGM (P2/P5), PPM (P3/P6) or PNG image", f"Netpbm {data[:2].decode()}")
        return _read_with_pillow(data)
    except _ImageProblem as problem:
        detail = problem.detail
        if referenced_by is not None:
            detail = (detail + "; " if detail else "") + f"image named in {referenced_by}"
        raise MapError(str(path), problem.expected, problem.got, detail=detail) from None


def _image_problem(name, expected, got=None, detail=""):
    """:func:`nhstab.safe_io.read_bytes`'s errors as an _ImageProblem (read_image names the file)."""
    return _ImageProblem(expected, got, detail=detail)


class _ImageProblem(Exception):
    """Raised by the image readers; :func:`read_image` turns it into a MapError naming the file."""

    def __init__(self, expected: str, got: object | None = None, *, detail: str = ""):
        super().__init__(expected)
        self.expected, self.got, self.detail = expected, got, detail


# --------------------------------------------------------------------------------------------------
# Image readers


def _read_netpbm(data: bytes) -> RasterImage:
    """Netpbm P2/P5 (grey) and P3/P6 (colour): comments allowed in the header, maxval 1..65535."""
    magic = data[:2]
    channels = 1 if magic in (b"P2", b"P5") else 3
    pos = 2
    header: list[int] = []
    for name in ("width", "height", "maxval"):
        start = pos
        while pos < len(data):
            byte = data[pos:pos + 1]
            if byte in _NETPBM_WHITESPACE:
                pos += 1
            elif byte == b"#":          # a comment runs to the end of the line
                ends = [i for i in (data.find(b"\n", pos), data.find(b"\r", pos)) if i >= 0]
                pos = min(ends) if ends else len(data)
            else:
                break
        if pos >= len(data):
            raise _ImageProblem("a complete PGM/PPM header", detail=f"file ends before the {name}")
        if pos == start:
            raise _ImageProblem("a PGM/PPM header with fields separated by whitespace",
                                detail=f"no separator before the {name}")
        match = _NETPBM_NUMBER.match(data, pos)
        if match is None:
            raise _ImageProblem(f"a decimal {name} in the PGM/PPM header", detail=f"found {data[pos:pos + 12]!r}")
        header.append(int(match.group()))
        pos = match.end()
    width, height, maxval = header
    if width < 1 or height < 1:
        raise _ImageProblem("an image of at least 1 x 1 pixels", f"{width} x {height}")
    _check_pixels(width, height)
    if not 1 <= maxval <= 65535:
        raise _ImageProblem("a PGM/PPM maxval in 1..65535", maxval)
    if pos >= len(data):
        raise _ImageProblem("PGM/PPM pixel data", detail="file ends after the header")
    if data[pos:pos + 1] not in _NETPBM_WHITESPACE:
        raise _ImageProblem("a single whitespace character after the PGM/PPM maxval",
                            detail=f"found {data[pos:pos + 1]!r}")
    pos += 1
    count = width * height * channels

    if magic in (b"P5", b"P6"):
        itemsize = 1 if maxval < 256 else 2
        raster = data[pos:pos + count * itemsize]
        if len(raster) < count * itemsize:
            raise _ImageProblem(f"{count * itemsize} bytes of pixel data for {width} x {height}",
                                f"{len(raster)} bytes", detail="truncated image")
        values = np.frombuffer(raster, dtype=np.uint8 if itemsize == 1 else ">u2").astype(np.int64)
    else:
        raster = re.sub(rb"#[^\n\r]*", b"", data[pos:])
        if re.fullmatch(rb"[0-9 \t\n\r\v\f]*", raster) is None:
            raise _ImageProblem("ASCII decimal pixel values", detail="corrupt plain PGM/PPM data")
        tokens = raster.split(None, count)[:count]
        if len(tokens) < count:
            raise _ImageProblem(f"{count} pixel values for {width} x {height}", f"{len(tokens)} values",
                                detail="truncated image")
        text = np.array(tokens)
        if text.dtype.itemsize > 5:
            raise _ImageProblem(f"pixel values at most maxval {maxval}", detail="value too long")
        values = text.astype(np.int64)
    if values.max(initial=0) > maxval:
        raise _ImageProblem(f"pixel values at most maxval {maxval}", int(values.max()), detail="corrupt image")
    if maxval == 65535:
        quanta = values.astype(np.float64)
    elif maxval == 255:
        quanta = values * 257.0
    else:
        quanta = np.floor(values * (QUANTUM_MAX / maxval) + 0.5)
    shape = (height, width) if channels == 1 else (height, width, 3)
    return RasterImage(quanta.reshape(shape))


def _check_png_chunks(data: bytes) -> None:
    """Walk the PNG chunks: each must be complete with a correct CRC, ending with IEND.

    Pillow accepts a file whose IEND (or IDAT CRC) is missing; a map image must be complete.
    """
    pos = 8
    while True:
        if pos + 8 > len(data):
            raise _ImageProblem("a complete PNG file", detail="truncated image: no IEND chunk")
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        end = pos + 8 + length + 4
        if end > len(data):
            raise _ImageProblem("a complete PNG file", detail=f"truncated image inside a {kind!r} chunk")
        (crc,) = struct.unpack(">I", data[end - 4:end])
        if zlib.crc32(data[pos + 4:end - 4]) & 0xFFFFFFFF != crc:
            raise _ImageProblem("a PNG file with valid chunk checksums", detail=f"corrupt {kind!r} chunk")
        if kind == b"IEND":
            return
        pos = end


def _read_with_pillow(data: bytes) -> RasterImage:
    if data[:8] == _PNG_SIGNATURE:
        _check_png_chunks(data)
    try:
        with _PILImage.open(io.BytesIO(data)) as im:
            _check_pixels(*im.size)             # before the pixels are decoded
            im.load()
            mode = im.mode
            transparent = "transparency" in im.info
            if mode in ("I;16", "I;16L", "I;16B", "I;16N", "I"):
                grey = np.asarray(im).astype(np.int64)
                if grey.min(initial=0) < 0 or grey.max(initial=0) > 65535:
                    raise _ImageProblem("a 16-bit grey image", detail=f"values outside 0..65535 in mode {mode}")
                alpha = None
                if transparent and isinstance(im.info["transparency"], int):
                    alpha = np.where(grey == im.info["transparency"], 0.0, QUANTUM_MAX)
                return RasterImage(grey.astype(np.float64), alpha)
            if mode == "L" and not transparent:
                return RasterImage(np.asarray(im, dtype=np.float64) * 257.0)
            if mode == "1":
                return RasterImage(np.asarray(im.convert("L"), dtype=np.float64) * 257.0)
            if mode in ("LA", "La") or (mode == "L" and transparent):
                la = np.asarray(im.convert("LA"), dtype=np.float64) * 257.0
                return RasterImage(la[..., 0], la[..., 1])
            if mode in ("RGBA", "RGBa", "PA") or transparent:
                rgba = np.asarray(im.convert("RGBA"), dtype=np.float64) * 257.0
                return RasterImage(rgba[..., :3], rgba[..., 3])
            rgb = np.asarray(im.convert("RGB"), dtype=np.float64) * 257.0
            return RasterImage(rgb)
    except _ImageProblem:
        raise
    except Exception as exc:  # noqa: BLE001 - Pillow raises many types for corrupt files
        raise _ImageProblem("a readable PGM or PNG image", type(exc).__name__, detail=_oneline(exc)) from None


def _check_pixels(width: int, height: int) -> None:
    if width * height > MAX_GRID_CELLS:
        raise _ImageProblem(f"an image of at most {MAX_GRID_CELLS:,} pixels (4096 x 4096)",
                            f"{width} x {height} = {width * height:,} pixels")


# --------------------------------------------------------------------------------------------------
# Helpers


def _number(path: Path, key: str, value) -> float:
    """A finite float from a YAML value: int, float, or a numeric string (yaml-cpp reads those)."""
    result = None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        try:
            result = float(value)
        except OverflowError:
            result = math.inf
    elif isinstance(value, str) and _FLOAT_TEXT.fullmatch(value.strip()):
        result = float(value.strip())
    if result is None:
        raise MapError(f"{path}:{key}", "a number", value)
    if not math.isfinite(result):
        raise MapError(f"{path}:{key}", "a finite number (no NaN or infinity)", value)
    return result


def _oneline(value) -> str:
    return " ".join(str(value).split())
