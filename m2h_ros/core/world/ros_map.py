"""nav2 map files without ROS: a ``map.yaml`` and its image, read as nav2_map_server's ``loadMapFromYaml``
reads them (map_io.cpp of nav2 1.3.7 and later: Jazzy since 2025, Kilted, Rolling) and written as
``map_saver_cli`` writes them. Humble's loader averaged R, G, B (and, in trinary, inverted alpha) and
compared strictly; for opaque grey images the two differ only at pixels exactly on a threshold.

Reading an image pixel (8 bits a channel):
* grey: colour is turned grey as GraphicsMagick's GrayscaleType does it, Rec. 601 luma
  0.299 R + 0.587 G + 0.114 B on 16-bit quanta, truncated back to 8 bits (a grey image keeps its values);
  alpha is not mixed in;
* ``occ = 1 - grey / 255`` (``grey / 255`` when ``negate``), in float32 as map_server computes it;
* trinary: ``occ >= occupied_thresh`` is OCCUPIED (100), ``occ <= free_thresh`` FREE (0), else UNKNOWN (-1);
* scale: as trinary, and in between ``round((occ - free_thresh) / (occupied_thresh - free_thresh) * 100)``;
* trinary and scale: a pixel with alpha below 255 is UNKNOWN;
* raw: the grey value itself when 0..100, else UNKNOWN (negate and alpha play no part).
The image's top row is the grid's last row: OccupancyGrid row 0 is the bottom (smallest y).

Beyond map_server, this reader refuses unknown keys (map_server ignores them, so a misspelt ``mode`` reads
the map as trinary), 16-bit images (map_server scales them to 8 bits), thresholds outside [0, 1] or not
ordered, and a resolution <= 0.
"""

from __future__ import annotations

import difflib
import hashlib
import io
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

from m2h_ros.core.world.frames import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from m2h_ros.errors import ConfigError, MapError

MODES = ("trinary", "scale", "raw")
IMAGE_FORMATS = ("pgm", "png")
# The keys map_saver writes, in its order; what each one says when it is missing.
KEYS = {
    "image": "the image file, relative to this file's folder (e.g. map.pgm)",
    "mode": "trinary, scale or raw (trinary when left out)",
    "resolution": "metres per pixel (e.g. 0.05)",
    "origin": "[x, y, yaw] of the bottom-left pixel's outer corner in the map frame (e.g. [0.0, 0.0, 0.0])",
    "negate": "0 when white is free and black occupied, as map_saver writes",
    "occupied_thresh": "0.65 as map_saver writes",
    "free_thresh": "0.196 as map_saver writes with a trinary image (0.25 with a scale one)",
}
OPTIONAL = frozenset({"mode"})
# map_saver's trinary pixels, and the thresholds it writes beside them (they split the three exactly).
FREE_PIXEL, OCCUPIED_PIXEL, UNKNOWN_PIXEL = 254, 0, 205
TRINARY_OCCUPIED_THRESH, TRINARY_FREE_THRESH = 0.65, 0.196
QUANTUM = 65535  # GraphicsMagick's 16-bit quantum range: map_server's and map_saver's pixel arithmetic


@dataclass(frozen=True)
class RosMap:
    """A map file as map_server loads it, plus map_server's trinary reading of the same pixels."""
    grid: OccupancyGrid  # what map_server publishes on /map
    trinary: np.ndarray  # (rows, cols) int8 FREE/OCCUPIED/UNKNOWN like grid.cells (the same array if trinary)
    yaml_path: Path
    image_path: Path
    sha256: str  # of the YAML's and the image's bytes: a cache key for what is built from the map
    mode: str
    negate: bool
    occupied_thresh: float
    free_thresh: float

    def occupied(self) -> np.ndarray:
        """Cells map_server would call occupied were the map trinary (see ``trinary``)."""
        return self.trinary == OCCUPIED

    def free(self) -> np.ndarray:
        return self.trinary == FREE

    def unknown(self) -> np.ndarray:
        return self.trinary == UNKNOWN


def read_ros_map(yaml_path: str | Path) -> RosMap:
    """Load a nav2 map (``map.yaml`` naming its image) as map_server does; MapError names the file, the
    key and the fix for anything map_server would refuse or misread.

    ``trinary`` (and ``occupied()``, ``free()``, ``unknown()``) reads the map as map_server reads a trinary
    map whatever the file's mode: for trinary and scale files, the pixels through the trinary rule (a
    scale file's in-between pixels are unknown); for raw files, whose pixels are occupancy in percent, a
    value >= occupied_thresh * 100 is occupied, a value <= free_thresh * 100 free, anything else unknown."""
    path = Path(yaml_path).expanduser()
    text = _read_bytes(path, what="map file", fix="pass the map.yaml that map_saver_cli wrote")
    try:
        document = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # libyaml when there
    except yaml.YAMLError as exc:
        raise MapError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from exc
    settings = _settings(document, path)
    image_path = Path(settings["image"])
    if not image_path.is_absolute():  # map_server: relative to the YAML file's folder
        image_path = path.parent / image_path
    image_bytes = _read_bytes(image_path, what=f"map image (named by {path})",
                              fix=f"the 'image' key is relative to {path.parent}")
    grey, alpha = _decode(image_bytes, image_path)
    # Image row 0 is the top; OccupancyGrid row 0 is the bottom.
    cells, trinary = _occupancy(grey[::-1], None if alpha is None else alpha[::-1], settings)
    x, y, yaw = settings["origin"]
    digest = hashlib.sha256()
    for part in (text, image_bytes):
        digest.update(len(part).to_bytes(8, "little"))
        digest.update(part)
    return RosMap(grid=OccupancyGrid(cells, settings["resolution"], (x, y), yaw),
                  trinary=trinary, yaml_path=path, image_path=image_path,
                  sha256=digest.hexdigest(), mode=settings["mode"], negate=settings["negate"],
                  occupied_thresh=settings["occupied_thresh"], free_thresh=settings["free_thresh"])


def write_ros_map(yaml_path: str | Path, grid: OccupancyGrid, *, image_format: str = "pgm",
                  mode: str = "trinary", negate: bool = False, occupied_thresh: float = 0.65,
                  free_thresh: float = 0.25) -> Path:
    """Write ``grid`` as map_saver_cli does: the image beside the YAML (same name, ``image_format``
    suffix) and the YAML naming it; each file through a temporary file and a rename. Returns the YAML's path.

    trinary: a cell <= round(free_thresh * 100) is 254, >= round(occupied_thresh * 100) is 0, anything else
    (unknown, in between) 205; the YAML then says 0.65 / 0.196 whatever the thresholds given, as map_saver
    does. scale (png only: unknown is transparent): grey (100 - cell) / 100. raw: the cell value, unknown
    255. ``negate`` (not map_saver's) writes trinary and scale images the other way round, negate: 1."""
    path = Path(yaml_path)
    where = f"writing map {path}"
    if path.suffix not in (".yaml", ".yml"):
        raise ConfigError(f"{where}: the map file's name must end in .yaml (the image goes beside it)")
    image_format = image_format.lower()
    if image_format not in IMAGE_FORMATS:
        raise ConfigError(f"{where}: image_format must be one of {', '.join(IMAGE_FORMATS)}, not {image_format!r}")
    mode = _mode(mode, where)
    if mode == "scale" and image_format != "png":
        raise ConfigError(f"{where}: mode scale marks unknown cells transparent; use image_format='png'")
    if mode == "raw" and negate:
        raise ConfigError(f"{where}: map_server ignores negate in raw mode; write raw maps with negate=False")
    _check_thresholds(float(occupied_thresh), float(free_thresh), where)
    cells = np.asarray(grid.cells)
    if cells.ndim != 2 or cells.size == 0 or not np.issubdtype(cells.dtype, np.integer):
        raise ConfigError(f"{where}: grid.cells must be a non-empty 2-D integer array, not {cells.dtype} "
                          f"{cells.shape}")
    if not (math.isfinite(grid.resolution) and grid.resolution > 0):
        raise ConfigError(f"{where}: grid.resolution must be > 0, not {grid.resolution}")
    rows = cells[::-1].astype(np.int16)  # image row 0 is the top
    known = (rows >= FREE) & (rows <= OCCUPIED)
    if mode == "trinary":
        pixels = np.full(rows.shape, UNKNOWN_PIXEL, np.uint8)
        pixels[known & (rows >= int(np.rint(occupied_thresh * 100)))] = OCCUPIED_PIXEL
        pixels[known & (rows <= int(np.rint(free_thresh * 100)))] = FREE_PIXEL
        if negate:
            pixels = 255 - pixels
        thresholds = TRINARY_OCCUPIED_THRESH, TRINARY_FREE_THRESH
    elif mode == "scale":
        shade = np.where(known, (rows if negate else 100 - rows) / 100.0, 0.5)  # unknown: transparent 0.5
        # map_saver: Magick::ColorGray truncates the shade to a 16-bit quantum, the 8-bit writer truncates it.
        grey = (np.floor(shade * QUANTUM).astype(np.int64) // 257).astype(np.uint8)
        pixels = np.stack([grey, grey, grey, np.where(known, 255, 0).astype(np.uint8)], axis=-1)
        thresholds = float(occupied_thresh), float(free_thresh)
    else:
        pixels = np.where(known, rows, 255).astype(np.uint8)
        thresholds = float(occupied_thresh), float(free_thresh)
    image_path = path.with_suffix(f".{image_format}")
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, "PPM" if image_format == "pgm" else "PNG")
    document = {"image": image_path.name, "mode": mode, "resolution": float(grid.resolution),
                "origin": [float(grid.origin[0]), float(grid.origin[1]), float(grid.yaw)],
                "negate": int(bool(negate)), "occupied_thresh": thresholds[0], "free_thresh": thresholds[1]}
    path.parent.mkdir(parents=True, exist_ok=True)
    _replace(image_path, buffer.getvalue())  # the image first: the YAML never names a half-written image
    _replace(path, yaml.safe_dump(document, sort_keys=False, default_flow_style=None).encode())
    return path


def _read_bytes(path: Path, *, what: str, fix: str) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError as exc:
        raise MapError(f"{path}: no such {what}; {fix}") from exc
    except IsADirectoryError as exc:
        raise MapError(f"{path}: is a folder, not a {what}; {fix}") from exc
    except OSError as exc:
        raise MapError(f"{path}: cannot read the {what} ({exc.strerror})") from exc


def _settings(document: object, path: Path) -> dict:
    """The map file's values, checked: map_server's keys, types and ranges."""
    if not isinstance(document, dict):
        raise MapError(f"{path}: a map file is a YAML mapping of {', '.join(KEYS)}; this one holds "
                       f"{type(document).__name__ if document is not None else 'nothing'}")
    for key in document:
        if key not in KEYS:
            nearest = difflib.get_close_matches(str(key), list(KEYS), n=1, cutoff=0.0)
            raise MapError(f"{path}: unknown key {key!r} (nearest known key: {nearest[0]!r}); a map file has "
                           f"the keys {', '.join(KEYS)}")
    for key, hint in KEYS.items():
        if key not in document and key not in OPTIONAL:
            raise MapError(f"{path}: missing key {key!r}: {hint}")
    image = document["image"]
    if not isinstance(image, str) or not image.strip():
        raise MapError(f"{path}: 'image' must name the map image: {KEYS['image']}, not {image!r}")
    resolution = _number(document["resolution"], path, "resolution")
    if resolution <= 0:
        raise MapError(f"{path}: resolution must be > 0 ({KEYS['resolution']}), not {resolution}")
    origin = document["origin"]
    if not isinstance(origin, list) or len(origin) != 3:
        raise MapError(f"{path}: origin must be 3 numbers, {KEYS['origin']}; not {origin!r}")
    negate = document["negate"]
    if not isinstance(negate, int):  # map_server: an int (non-zero is true), else a YAML boolean
        raise MapError(f"{path}: negate must be 0 or 1 (or true / false), not {negate!r}")
    occupied_thresh = _number(document["occupied_thresh"], path, "occupied_thresh")
    free_thresh = _number(document["free_thresh"], path, "free_thresh")
    _check_thresholds(occupied_thresh, free_thresh, str(path))
    return {"image": image, "mode": _mode(document.get("mode", "trinary"), str(path)),
            "resolution": resolution, "origin": tuple(_number(v, path, "origin") for v in origin),
            "negate": bool(negate), "occupied_thresh": occupied_thresh, "free_thresh": free_thresh}


def _number(value: object, path: Path, key: str) -> float:
    """A finite number; a quoted one too, as yaml-cpp converts any scalar text."""
    if not isinstance(value, bool):
        try:
            number = float(value) if isinstance(value, (int, float, str)) else math.nan
        except ValueError:
            number = math.nan
        if math.isfinite(number):
            return number
    raise MapError(f"{path}: {key} must be a finite number ({KEYS[key]}), not {value!r}")


def _mode(mode: object, where: str) -> str:
    if isinstance(mode, str) and mode.lower() in MODES:  # map_server lower-cases it
        return mode.lower()
    nearest = difflib.get_close_matches(str(mode).lower(), MODES, n=1, cutoff=0.0)
    raise MapError(f"{where}: mode {mode!r} is not a map_server mode (nearest: {nearest[0]!r}); use one of "
                   f"{', '.join(MODES)}")


def _check_thresholds(occupied_thresh: float, free_thresh: float, where: str) -> None:
    for key, value in (("occupied_thresh", occupied_thresh), ("free_thresh", free_thresh)):
        if not 0.0 <= value <= 1.0:
            raise MapError(f"{where}: {key} {value} is outside [0, 1]: it is a fraction of full darkness "
                           f"({KEYS[key]})")
    if free_thresh >= occupied_thresh:
        raise MapError(f"{where}: free_thresh ({free_thresh}) must be below occupied_thresh "
                       f"({occupied_thresh}); map_saver writes 0.196 and 0.65")


def _decode(data: bytes, path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(grey, alpha or None), each (rows, cols) uint8, top row first, as map_server sees the image."""
    if not data:
        raise MapError(f"{path}: the map image is empty (0 bytes); write it again with map_saver_cli")
    try:
        with Image.open(io.BytesIO(data)) as image:
            # Pillow reads 16-bit grey as mode I or I;16 and 16-bit colour as 8-bit RGB(A) (the tile says).
            wide = image.mode.startswith("I") or any(isinstance(tile.args, str) and ";16" in tile.args
                                                     for tile in image.tile)
            if not wide and image.mode != "F":
                image.load()
                pixels, mode = _channels(image)
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
        raise MapError(f"{path}: cannot read the map image ({exc}); map_server's images are 8-bit PGM "
                       f"or PNG") from exc
    if wide or image.mode == "F":
        raise MapError(f"{path}: a {16 if wide else 32}-bit image (Pillow mode {image.mode}); map images have "
                       f"8 bits a channel: save it as 8-bit grey")
    if mode not in ("L", "LA", "RGB", "RGBA"):
        raise MapError(f"{path}: a {mode} image; save the map image as 8-bit grey (or RGB) PGM or PNG")
    if pixels.size == 0:
        raise MapError(f"{path}: the map image has no pixels ({pixels.shape[1]} x {pixels.shape[0]})")
    if mode in ("L", "LA"):
        grey = pixels if mode == "L" else pixels[..., 0]
    elif np.array_equal(pixels[..., 0], pixels[..., 1]) and np.array_equal(pixels[..., 1], pixels[..., 2]):
        grey = pixels[..., 0]  # a grey pixel's luma is its value (map_saver's scale images are grey RGBA)
    else:
        # GraphicsMagick's GrayscaleType: float32 Rec. 601 luma of 16-bit quanta, rounded; then truncated
        # to 8 bits. This matches `gm convert -type Grayscale` for all 2^24 colours.
        quanta = pixels[..., :3].astype(np.float32) * np.float32(257)
        luma = (np.float32(0.299) * quanta[..., 0] + np.float32(0.587) * quanta[..., 1]
                + np.float32(0.114) * quanta[..., 2] + np.float32(0.5))
        grey = (np.floor(luma).astype(np.int32) // 257).astype(np.uint8)
    return np.ascontiguousarray(grey), (np.ascontiguousarray(pixels[..., -1]) if mode in ("LA", "RGBA") else None)


def _channels(image: Image.Image) -> tuple[np.ndarray, str]:
    """The pixels as grey or RGB, with alpha where the image has any (a tRNS colour or palette entry too)."""
    if image.mode == "1":
        image = image.convert("L")
    transparent = "transparency" in image.info
    if image.mode == "P":
        image = image.convert("RGBA" if transparent else "RGB")
    elif image.mode in ("L", "RGB") and transparent:
        image = image.convert(f"{image.mode}A")
    elif image.mode in ("PA", "RGBa", "La"):
        image = image.convert("LA" if image.mode == "La" else "RGBA")
    return np.asarray(image), image.mode


def _occupancy(grey: np.ndarray, alpha: np.ndarray | None, settings: dict) -> tuple[np.ndarray, np.ndarray]:
    """(cells as map_server fills them, the trinary reading; one array for a trinary map), in the rows'
    order of ``grey``: each of the 256 grey levels is worked out once, then looked up."""
    cells_of, trinary_of = _levels(settings)
    cells = np.take(cells_of, grey)
    trinary = cells if settings["mode"] == "trinary" else np.take(trinary_of, grey)
    if alpha is not None and settings["mode"] != "raw":
        translucent = alpha < 255
        cells = np.where(translucent, np.int8(UNKNOWN), cells)
        trinary = cells if settings["mode"] == "trinary" else np.where(translucent, np.int8(UNKNOWN), trinary)
    return cells, trinary


def _levels(settings: dict) -> tuple[np.ndarray, np.ndarray]:
    """(256,) int8 cell value and trinary reading of each grey level."""
    occupied_thresh, free_thresh = settings["occupied_thresh"], settings["free_thresh"]
    grey = np.arange(256)
    if settings["mode"] == "raw":
        cells = np.where(grey <= OCCUPIED, grey, UNKNOWN).astype(np.int8)
        trinary = np.full(grey.shape, UNKNOWN, np.int8)
        trinary[(cells >= 0) & (cells >= occupied_thresh * 100)] = OCCUPIED
        trinary[(cells >= 0) & (cells <= free_thresh * 100)] = FREE
        return cells, trinary
    # Eigen's float arithmetic in map_server: thresholds become float32 where they meet the pixels.
    occ_f, free_f = np.float32(occupied_thresh), np.float32(free_thresh)
    shade = grey.astype(np.float32) / np.float32(255)
    occ = shade if settings["negate"] else np.float32(1) - shade
    trinary = np.full(grey.shape, UNKNOWN, np.int8)
    trinary[occ >= occ_f] = OCCUPIED
    trinary[occ <= free_f] = FREE
    if settings["mode"] == "trinary":
        return trinary, trinary
    cells = trinary.copy()
    between = (occ > free_f) & (occ < occ_f)
    scaled = (occ[between] - free_f) / np.float32(occupied_thresh - free_thresh) * np.float32(100)
    whole = np.trunc(scaled)
    cells[between] = (whole + (scaled - whole >= 0.5)).astype(np.int8)  # std::round: halves away from 0
    return cells, trinary


def _replace(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename: readers see the old or the new file."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        with open(tmp, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
