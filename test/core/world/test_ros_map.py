"""nav2 map files (map.yaml + image) read as nav2_map_server reads them and written as map_saver_cli
writes them; the scripted apartment and corridor plans."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image
from scipy import ndimage

from m2h_ros.core.world.frames import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from m2h_ros.core.world.ros_map import read_ros_map, write_ros_map
from m2h_ros.core.world.sample_worlds import (APARTMENT_DOORS, APARTMENT_FURNITURE, APARTMENT_ROOMS,
                                              apartment_grid, apartment_to_map, corridor_grid)
from m2h_ros.errors import ConfigError, MapError
from scripts_as_modules import load_script

REPO = Path(__file__).resolve().parents[3]
SAVER_KEYS = ["image", "mode", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"]


def write_map(folder: Path, pixels, *, image: object = "map.pgm", name: str = "map.yaml", **keys) -> Path:
    """A map file as a user might have it: ``pixels`` (top row first) saved by Pillow, YAML keys over
    map_saver's trinary defaults (a key set to None is left out)."""
    saved = Path(image if isinstance(image, str) and image else "map.pgm")  # also when the key is bad
    image_path = saved if saved.is_absolute() else folder / saved
    image_path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.asarray(pixels, np.uint8)).save(image_path)
    document = {"image": image, "mode": "trinary", "resolution": 0.05, "origin": [0.0, 0.0, 0.0],
                "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196} | keys
    path = folder / name
    path.write_text(yaml.safe_dump({k: v for k, v in document.items() if v is not None}))
    return path


def top_first(cells: np.ndarray) -> list:
    """Grid cells in the image's row order (the grid's row 0 is the image's bottom row)."""
    return np.asarray(cells)[::-1].tolist()


# --- reading: each mode as map_server computes it --------------------------------------------------

def test_trinary_reads_map_saver_pixels_and_flips_rows(tmp_path):
    pixels = [[254, 0, 205], [255, 89, 90]]  # free, occupied, unknown / free, just dark enough, just not
    ros_map = read_ros_map(write_map(tmp_path, pixels))
    assert top_first(ros_map.grid.cells) == [[FREE, OCCUPIED, UNKNOWN], [FREE, OCCUPIED, UNKNOWN]]
    assert ros_map.grid.cells[0].tolist() == [FREE, OCCUPIED, UNKNOWN]  # row 0: the image's bottom row
    assert ros_map.grid.cells.dtype == np.int8 and ros_map.grid.resolution == 0.05
    assert ros_map.mode == "trinary" and ros_map.image_path == tmp_path / "map.pgm"


def test_thresholds_are_inclusive(tmp_path):
    # With negate, occ = grey / 255: 51 / 255 is exactly free_thresh 0.2, 153 / 255 exactly occupied 0.6
    # (map_server since Jazzy compares with <= and >=; Humble's loop compared strictly).
    ros_map = read_ros_map(write_map(tmp_path, [[51, 52, 152, 153]], negate=1, free_thresh=0.2,
                                     occupied_thresh=0.6))
    assert top_first(ros_map.grid.cells) == [[FREE, UNKNOWN, UNKNOWN, OCCUPIED]]


def test_negate_makes_black_free(tmp_path):
    ros_map = read_ros_map(write_map(tmp_path, [[0, 255, 128]], negate=True))
    assert top_first(ros_map.grid.cells) == [[FREE, OCCUPIED, UNKNOWN]]
    assert ros_map.negate is True


def test_scale_mode_scales_between_the_thresholds(tmp_path):
    # occ = 1 - grey / 255; between free 0.25 and occupied 0.65: round((occ - 0.25) / 0.4 * 100).
    grey = [255, 191, 127, 100, 90, 89, 0]
    expected = [FREE, round((1 - 191 / 255 - 0.25) / 0.4 * 100), round((1 - 127 / 255 - 0.25) / 0.4 * 100),
                round((1 - 100 / 255 - 0.25) / 0.4 * 100), round((1 - 90 / 255 - 0.25) / 0.4 * 100),
                OCCUPIED, OCCUPIED]
    ros_map = read_ros_map(write_map(tmp_path, [grey], image="map.png", mode="scale", free_thresh=0.25))
    assert top_first(ros_map.grid.cells) == [expected]
    assert expected[1:5] == [0, 63, 89, 99]
    # map_server's trinary reading of the same pixels: in-between values are unknown.
    assert top_first(ros_map.trinary) == [[FREE, UNKNOWN, UNKNOWN, UNKNOWN, UNKNOWN, OCCUPIED, OCCUPIED]]


def test_scale_rounds_halves_away_from_zero(tmp_path):
    # With negate, occ = 51 / 255 = 0.2 and (0.2 - 0) / 0.32 * 100 is 62.5 exactly in float32: std::round
    # makes it 63 (rounding halves to even would make it 62).
    ros_map = read_ros_map(write_map(tmp_path, [[51]], image="map.png", mode="scale", negate=1,
                                     free_thresh=0.0, occupied_thresh=0.32))
    assert ros_map.grid.cells.tolist() == [[63]]


def test_scale_and_trinary_make_translucent_pixels_unknown_and_do_not_average_alpha(tmp_path):
    # Humble averaged alpha in as a fourth channel (white at alpha 128 was free); since Jazzy any alpha
    # below 255 is unknown. The second row is opaque: alpha flips with the rows.
    rgba = [[[255, 255, 255, 255], [255, 255, 255, 128], [0, 0, 0, 0], [0, 0, 0, 255]],
            [[255, 255, 255, 255], [255, 255, 255, 255], [0, 0, 0, 255], [0, 0, 0, 255]]]
    for mode in ("trinary", "scale"):
        ros_map = read_ros_map(write_map(tmp_path, rgba, image="map.png", mode=mode, free_thresh=0.25))
        assert top_first(ros_map.grid.cells) == [[FREE, UNKNOWN, UNKNOWN, OCCUPIED],
                                                 [FREE, FREE, OCCUPIED, OCCUPIED]], mode


def test_raw_mode_keeps_values_up_to_100_and_ignores_negate_and_alpha(tmp_path):
    grey = [0, 19, 20, 37, 64, 65, 100, 101, 205, 255]
    for negate, image in ((0, [grey]), (1, [[[v, 255 - (v % 2) * 255] for v in grey]])):
        ros_map = read_ros_map(write_map(tmp_path, image, image="map.png", mode="raw", negate=negate))
        assert top_first(ros_map.grid.cells) == [[0, 19, 20, 37, 64, 65, 100, -1, -1, -1]]
        # Trinary reading of raw values: >= 65 occupied, <= 19.6 free, the rest unknown.
        assert top_first(ros_map.trinary) == [[FREE, FREE, UNKNOWN, UNKNOWN, UNKNOWN, OCCUPIED, OCCUPIED,
                                               UNKNOWN, UNKNOWN, UNKNOWN]]


def test_masks_follow_the_trinary_reading(tmp_path):
    ros_map = read_ros_map(write_map(tmp_path, [[254, 0, 205, 30]], mode="raw"))
    # Raw: 254 and 205 are over 100 (unknown), 0 is free, 30 between the thresholds (unknown).
    assert top_first(ros_map.free()) == [[False, True, False, False]]
    assert not ros_map.occupied().any()
    assert top_first(ros_map.unknown()) == [[True, False, True, True]]
    ros_map = read_ros_map(write_map(tmp_path, [[254, 0, 205, 30]]))
    assert top_first(ros_map.free()) == [[True, False, False, False]]
    assert top_first(ros_map.occupied()) == [[False, True, False, True]]
    assert top_first(ros_map.unknown()) == [[False, False, True, False]]


def test_mode_is_case_insensitive_and_defaults_to_trinary(tmp_path):
    assert read_ros_map(write_map(tmp_path, [[254]], mode="Scale", image="m.png")).mode == "scale"
    assert read_ros_map(write_map(tmp_path, [[254]], mode=None)).mode == "trinary"


# --- colour: GraphicsMagick's grey -------------------------------------------------------------------

def test_colour_turns_grey_as_graphicsmagick_does(tmp_path):
    # Reference greys from `gm convert -type Grayscale` (GraphicsMagick 1.3.40 Q16), read back in raw
    # mode (cell = grey). Rec. 601 luma, truncated: a plain rounding or a channel mean differs on these.
    colours = {(26, 23, 208): 44, (60, 58, 172): 71, (16, 32, 48): 29, (255, 0, 0): 76, (0, 0, 255): 29,
               (0, 0, 0): 0, (100, 100, 100): 100}
    rgb = [list(colours)]
    ros_map = read_ros_map(write_map(tmp_path, rgb, image="map.png", mode="raw"))
    assert top_first(ros_map.grid.cells) == [list(colours.values())]
    rgba = [[[*c, 255] for c in colours]]
    ros_map = read_ros_map(write_map(tmp_path, rgba, image="map.png", mode="raw"))
    assert top_first(ros_map.grid.cells) == [list(colours.values())]


def test_colour_greys_above_100_by_thresholds(tmp_path):
    # More GraphicsMagick greys, each placed against a threshold it must fall on: (254, 254, 253) is 253,
    # not 254 (so with negate, occ = 253/255 falls below 254/255); (187, 139, 162) is 155.
    grey_253 = read_ros_map(write_map(tmp_path, [[[254, 254, 253]]], image="map.png", negate=1,
                                      free_thresh=0.5, occupied_thresh=253.5 / 255))
    assert top_first(grey_253.grid.cells) == [[UNKNOWN]]
    grey_155 = read_ros_map(write_map(tmp_path, [[[187, 139, 162], [155, 155, 155], [156, 156, 156]]],
                                      image="map.png", negate=1, free_thresh=0.1, occupied_thresh=155.5 / 255))
    assert top_first(grey_155.grid.cells) == [[UNKNOWN, UNKNOWN, OCCUPIED]]


def test_palette_grey_alpha_and_bilevel_images(tmp_path):
    palette = Image.new("P", (3, 1))
    palette.putpalette([255, 255, 255, 0, 0, 0, 200, 200, 200])
    palette.putdata([0, 1, 2])
    palette.save(tmp_path / "p.png", transparency=2)  # the third entry is transparent
    path = write_map(tmp_path, [[0]], image="unused.png", name="p.yaml")
    path.write_text(path.read_text().replace("unused.png", "p.png"))
    assert top_first(read_ros_map(path).grid.cells) == [[FREE, OCCUPIED, UNKNOWN]]
    ros_map = read_ros_map(write_map(tmp_path, [[[255, 255], [0, 255], [255, 0]]], image="la.png"))
    assert top_first(ros_map.grid.cells) == [[FREE, OCCUPIED, UNKNOWN]]
    Image.fromarray(np.array([[True, False]])).save(tmp_path / "bits.png")
    path.write_text(path.read_text().replace("p.png", "bits.png"))
    assert top_first(read_ros_map(path).grid.cells) == [[FREE, OCCUPIED]]


def test_pgm_and_png_of_the_same_pixels_read_the_same(tmp_path):
    pixels = np.random.default_rng(3).integers(0, 256, (7, 5))
    pgm = read_ros_map(write_map(tmp_path, pixels, image="a.pgm", name="a.yaml", mode="scale"))
    png = read_ros_map(write_map(tmp_path, pixels, image="b.png", name="b.yaml", mode="scale"))
    np.testing.assert_array_equal(pgm.grid.cells, png.grid.cells)
    assert pgm.grid.cells.shape == (7, 5)


# --- geometry and paths ----------------------------------------------------------------------------

def test_rotated_origin_places_a_known_pixel(tmp_path):
    pixels = np.full((3, 4), 254)
    pixels[0, 3] = 0  # top row, last column: cell (ix 3, iy 2)
    ros_map = read_ros_map(write_map(tmp_path, pixels, resolution=0.5, origin=[1.0, 2.0, math.pi / 2]))
    grid = ros_map.grid
    assert grid.origin == (1.0, 2.0) and grid.yaw == pytest.approx(math.pi / 2)
    assert grid.cells[2, 3] == OCCUPIED and (grid.cells == OCCUPIED).sum() == 1
    # Cell centre (3.5, 2.5) cells along the grid's x and y; the grid's x is the map's +y.
    centre = grid.cell_centres(3, 2)
    np.testing.assert_allclose(centre, [1.0 - 2.5 * 0.5, 2.0 + 3.5 * 0.5], atol=1e-12)
    assert tuple(int(i) for i in grid.cell_of(centre)) == (3, 2)


def test_image_path_is_relative_to_the_yaml_folder_not_the_working_folder(tmp_path, monkeypatch):
    maps = tmp_path / "maps"
    maps.mkdir()
    path = write_map(maps, [[0, 254]], image="images/floor.pgm")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    ros_map = read_ros_map(Path("..") / "maps" / "map.yaml")
    assert ros_map.image_path.resolve() == (maps / "images" / "floor.pgm").resolve()
    assert top_first(ros_map.grid.cells) == [[OCCUPIED, FREE]]
    absolute = write_map(maps, [[254, 0]], image=str(tmp_path / "abs.png"), name="abs.yaml")
    assert top_first(read_ros_map(absolute).grid.cells) == [[FREE, OCCUPIED]]
    assert path.exists()


def test_map_saver_yaml_text_is_accepted(tmp_path):
    Image.fromarray(np.array([[254, 0, 205]], np.uint8)).save(tmp_path / "saved.pgm")
    path = tmp_path / "saved.yaml"
    # As map_saver_cli writes it (3-decimal strings for resolution and origin).
    path.write_text("image: saved.pgm\nmode: trinary\nresolution: 0.050\norigin: [-10.000, -7.500, 0]\n"
                    "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    ros_map = read_ros_map(path)
    assert ros_map.grid.origin == (-10.0, -7.5) and ros_map.grid.resolution == 0.05
    assert top_first(ros_map.grid.cells) == [[FREE, OCCUPIED, UNKNOWN]]
    quoted = tmp_path / "quoted.yaml"  # yaml-cpp converts quoted numbers too
    quoted.write_text(path.read_text().replace("0.050", '"0.05"').replace("negate: 0", "negate: false"))
    assert read_ros_map(quoted).grid.resolution == 0.05


def test_sha256_covers_the_yaml_and_the_image(tmp_path):
    first = read_ros_map(write_map(tmp_path / "a", [[0, 254]]))
    same = read_ros_map(write_map(tmp_path / "b", [[0, 254]]))
    other_image = read_ros_map(write_map(tmp_path / "c", [[0, 205]]))
    other_yaml = read_ros_map(write_map(tmp_path / "d", [[0, 254]], resolution=0.1))
    assert first.sha256 == same.sha256 and len(first.sha256) == 64
    assert len({first.sha256, other_image.sha256, other_yaml.sha256}) == 3


# --- bad input: MapError naming the file, the key and the fix --------------------------------------

def raises_map_error(path: Path, *fragments: str) -> str:
    with pytest.raises(MapError) as info:
        read_ros_map(path)
    message = str(info.value)
    assert isinstance(info.value, ConfigError)
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_missing_or_malformed_yaml(tmp_path):
    raises_map_error(tmp_path / "nope.yaml", str(tmp_path / "nope.yaml"), "no such map file", "map_saver_cli")
    raises_map_error(tmp_path, str(tmp_path), "folder")
    listed = tmp_path / "list.yaml"
    listed.write_text("- image\n- resolution\n")
    raises_map_error(listed, str(listed), "mapping", "list")
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    raises_map_error(empty, str(empty), "nothing")
    broken = tmp_path / "broken.yaml"
    broken.write_text("image: [map.pgm\n")
    raises_map_error(broken, str(broken), "not valid YAML", "line")


def test_unknown_key_names_the_nearest_known_key(tmp_path):
    path = write_map(tmp_path, [[0]], negat=1, negate=None)
    raises_map_error(path, str(path), "'negat'", "nearest known key: 'negate'")
    path = write_map(tmp_path, [[0]], resolutoin=0.05)
    raises_map_error(path, "'resolutoin'", "'resolution'")


@pytest.mark.parametrize("key", ["image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"])
def test_missing_required_key(tmp_path, key):
    path = write_map(tmp_path, [[0]], **{key: None})
    raises_map_error(path, str(path), f"missing key '{key}'")


def test_missing_unreadable_empty_and_deep_images(tmp_path):
    path = write_map(tmp_path, [[0]])
    (tmp_path / "map.pgm").unlink()
    raises_map_error(path, str(tmp_path / "map.pgm"), "no such map image", str(path), "relative to")
    (tmp_path / "map.pgm").write_bytes(b"")
    raises_map_error(path, str(tmp_path / "map.pgm"), "empty")
    (tmp_path / "map.pgm").write_text("not an image")
    raises_map_error(path, str(tmp_path / "map.pgm"), "cannot read the map image")
    (tmp_path / "map.pgm").write_bytes(b"P5\n2 1\n65535\n" + np.array([0, 65535], ">u2").tobytes())
    raises_map_error(path, str(tmp_path / "map.pgm"), "16-bit", "8-bit")
    deep_png = write_map(tmp_path, [[0]], image="deep.png", name="deep.yaml")
    Image.fromarray(np.array([[0, 40000]], np.uint16)).save(tmp_path / "deep.png")
    raises_map_error(deep_png, str(tmp_path / "deep.png"), "16-bit")
    rgb16 = tmp_path / "rgb16.png"  # Pillow narrows 16-bit colour to 8 bits silently; its tile says 16
    rgb16.write_bytes(_png_rgb16())
    deep_png.write_text(deep_png.read_text().replace("deep.png", "rgb16.png"))
    raises_map_error(deep_png, str(rgb16), "16-bit")
    blank = write_map(tmp_path, [[0]], image="", name="blank.yaml")
    raises_map_error(blank, str(blank), "'image' must name the map image")


def _png_rgb16() -> bytes:
    """A 1 x 1 PNG of 16-bit RGB (Pillow cannot write one)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    header = struct.pack(">IIBBBBB", 1, 1, 16, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(b"\x00" + b"\xff\xff" * 3)) + chunk(b"IEND", b""))


@pytest.mark.parametrize(("keys", "fragments"), [
    ({"mode": "trinery"}, ["mode 'trinery'", "nearest: 'trinary'", "trinary, scale, raw"]),
    ({"mode": 3}, ["mode 3"]),
    ({"occupied_thresh": 1.5}, ["occupied_thresh 1.5 is outside [0, 1]"]),
    ({"free_thresh": -0.1}, ["free_thresh -0.1 is outside [0, 1]"]),
    ({"free_thresh": 0.7}, ["free_thresh (0.7) must be below occupied_thresh (0.65)"]),
    ({"free_thresh": 0.65}, ["must be below occupied_thresh"]),
    ({"resolution": 0}, ["resolution must be > 0"]),
    ({"resolution": -0.05}, ["resolution must be > 0"]),
    ({"resolution": "fine"}, ["resolution must be a finite number", "'fine'"]),
    ({"resolution": float("nan")}, ["resolution must be a finite number"]),
    ({"origin": [1.0, 2.0]}, ["origin must be 3 numbers", "[x, y, yaw]"]),
    ({"origin": "0 0 0"}, ["origin must be 3 numbers"]),
    ({"origin": [1.0, 2.0, "a"]}, ["origin must be a finite number"]),
    ({"negate": 0.5}, ["negate must be 0 or 1"]),
    ({"image": 7}, ["'image' must name the map image"]),
])
def test_bad_values_name_the_key_and_the_fix(tmp_path, keys, fragments):
    path = write_map(tmp_path, [[0]], **keys)
    raises_map_error(path, str(path), *fragments)


# --- writing as map_saver_cli ----------------------------------------------------------------------

def sample_grid(*, yaw: float = 0.0) -> OccupancyGrid:
    cells = np.array([[UNKNOWN, FREE, OCCUPIED, 50], [FREE, 25, 65, 100], [-1, 0, 100, 0]], np.int8)
    return OccupancyGrid(cells, 0.05, (-1.25, 2.5), yaw)


def test_write_trinary_as_map_saver(tmp_path):
    path = write_ros_map(tmp_path / "map.yaml", sample_grid(yaw=0.25))
    assert yaml.safe_load(path.read_text()) == {"image": "map.pgm", "mode": "trinary", "resolution": 0.05,
                                                "origin": [-1.25, 2.5, 0.25], "negate": 0,
                                                "occupied_thresh": 0.65, "free_thresh": 0.196}
    assert list(yaml.safe_load(path.read_text())) == SAVER_KEYS
    with Image.open(tmp_path / "map.pgm") as image:
        assert image.format == "PPM" and image.mode == "L"
        # Top row first: the grid's last row. <= 25 free (254), >= 65 occupied (0), else unknown (205).
        assert np.asarray(image).tolist() == [[205, 254, 0, 254], [254, 254, 0, 0], [205, 254, 0, 205]]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.pgm", "map.yaml"]  # no temporary left


def test_write_then_read_round_trips(tmp_path):
    grid = sample_grid(yaw=-2.0)
    expected_trinary = np.where(grid.cells < 0, UNKNOWN, np.where(grid.cells <= 25, FREE,
                                np.where(grid.cells >= 65, OCCUPIED, UNKNOWN)))
    for image_format in ("pgm", "png"):
        for negate in (False, True):
            back = read_ros_map(write_ros_map(tmp_path / f"{image_format}{negate}.yaml", grid,
                                              image_format=image_format, negate=negate))
            np.testing.assert_array_equal(back.grid.cells, expected_trinary)
            assert (back.grid.origin, back.grid.yaw, back.grid.resolution) == ((-1.25, 2.5), -2.0, 0.05)
            assert back.negate is negate
    raw = read_ros_map(write_ros_map(tmp_path / "raw.yaml", grid, mode="raw"))
    np.testing.assert_array_equal(raw.grid.cells, grid.cells)  # raw keeps every value
    with Image.open(tmp_path / "raw.pgm") as image:  # the value itself, unknown 255
        assert np.asarray(image).tolist() == [[255, 0, 100, 0], [0, 25, 65, 100], [255, 0, 100, 50]]
    every = OccupancyGrid(np.arange(-1, 101, dtype=np.int8).reshape(6, 17), 0.1, (0.0, 0.0))
    np.testing.assert_array_equal(read_ros_map(write_ros_map(tmp_path / "all.yaml", every, mode="raw",
                                                             image_format="png")).grid.cells, every.cells)


def test_write_scale_as_map_saver(tmp_path):
    grid = sample_grid()
    path = write_ros_map(tmp_path / "scale.yaml", grid, mode="scale", image_format="png")
    with Image.open(tmp_path / "scale.png") as image:
        assert image.mode == "RGBA"
        pixels = np.asarray(image)
    # Grey (100 - cell) / 100 truncated to 16 then 8 bits: 50 -> 127 (not 128); unknown transparent grey.
    assert pixels[0, :, 0].tolist() == [127, 255, 0, 255] and pixels[0, :, 3].tolist() == [0, 255, 255, 255]
    assert (pixels[..., 0] == pixels[..., 1]).all() and (pixels[..., 0] == pixels[..., 2]).all()
    assert pixels[2, 3, 0] == 127 and pixels[1, 1, 0] == 191 and pixels[1, 2, 0] == 89
    back = read_ros_map(path)
    assert back.mode == "scale" and back.free_thresh == 0.25
    assert top_first(back.grid.cells) == [[UNKNOWN, FREE, OCCUPIED, FREE], [FREE, 0, 100, 100],
                                          [UNKNOWN, FREE, OCCUPIED, 63]]


@pytest.mark.parametrize(("options", "fragment"), [
    ({"mode": "scale"}, "image_format='png'"),
    ({"image_format": "jpg"}, "image_format must be one of pgm, png"),
    ({"mode": "raw", "negate": True}, "negate"),
    ({"mode": "ternary"}, "nearest: 'trinary'"),
    ({"free_thresh": 0.7}, "must be below occupied_thresh"),
])
def test_write_refuses_what_map_server_would_misread(tmp_path, options, fragment):
    with pytest.raises(ConfigError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        write_ros_map(tmp_path / "map.yaml", sample_grid(), **options)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ConfigError, match=r"\.yaml"):
        write_ros_map(tmp_path / "map.pgm", sample_grid())


# --- the scripted apartment and corridor ------------------------------------------------------------

def cells_at(grid: OccupancyGrid, plan_points, *, yaw: float = 0.0) -> np.ndarray:
    ix, iy = grid.cell_of(apartment_to_map(plan_points, yaw=yaw))
    return grid.cells[iy, ix]


def centre(rect) -> tuple[float, float]:
    return (rect[0] + rect[2]) / 2, (rect[1] + rect[3]) / 2


@pytest.mark.parametrize("resolution", [0.05, 0.1])
def test_apartment_rooms_join_through_doors_only(resolution):
    grid = apartment_grid(resolution=resolution)
    free = grid.cells == FREE
    labels, count = ndimage.label(free)  # 4-connected
    assert count == 1
    assert 90 <= free.sum() * resolution ** 2 <= 100  # m^2 of floor
    assert np.all(cells_at(grid, [centre(r) for r in APARTMENT_ROOMS.values()]) == FREE)
    # Close every door: each room becomes its own region.
    closed = grid.cells.copy()
    for door in APARTMENT_DOORS.values():
        ix, iy = grid.cell_of(apartment_to_map([(door[0], door[1]), (door[2], door[3])]))
        closed[iy[0]:iy[1] + 1, ix[0]:ix[1] + 1] = OCCUPIED
    labels, count = ndimage.label(closed == FREE)
    ix, iy = grid.cell_of(apartment_to_map([centre(r) for r in APARTMENT_ROOMS.values()]))
    assert count == len(APARTMENT_ROOMS) == 6 and len(set(labels[iy, ix].tolist())) == 6


def test_apartment_walls_doors_furniture_and_margin():
    grid = apartment_grid()
    # A 0.85 m door is 17 cells at 5 cm; inner walls 2 cells, outer walls 3.
    row = grid.cells[grid.cell_of(apartment_to_map([(0, 4.0)]))[1][0]]  # along the wall at y = 4.0
    gaps = np.diff(np.flatnonzero(np.diff(np.r_[False, row == FREE, False].astype(int))))[::2]
    assert sorted(gaps.tolist()) == [17, 17]
    column = grid.cells[:, grid.cell_of(apartment_to_map([(2.0, 0.0)]))[0][0]]
    assert (column[20:23] == OCCUPIED).all() and column[23] == FREE  # outer wall from y = 0 to 0.15
    for name, rect in APARTMENT_FURNITURE.items():
        x0, y0, x1, y1 = rect
        assert cells_at(grid, [centre(rect)]) == OCCUPIED, name
        ring = [(x0 - 0.1, y0 - 0.1), (x1 + 0.1, y1 + 0.1), (x0 - 0.1, y1 + 0.1), (x1 + 0.1, y0 - 0.1)]
        assert np.all(cells_at(grid, ring) == FREE), name  # isolated: free all round
    margin = 20  # 1 m of unknown at 5 cm
    assert grid.cells.shape == (220, 280)
    for edge in (grid.cells[:margin], grid.cells[-margin:], grid.cells[:, :margin], grid.cells[:, -margin:]):
        assert (edge == UNKNOWN).all()


def test_apartment_yaw_turns_the_map_about_its_centre():
    yaw = 0.7
    grid = apartment_grid(yaw=yaw)
    np.testing.assert_array_equal(grid.cells, apartment_grid().cells)  # the same raster, placed turned
    assert grid.yaw == yaw
    table = centre(APARTMENT_FURNITURE["table"])
    assert cells_at(grid, [table], yaw=yaw) == OCCUPIED
    np.testing.assert_allclose(apartment_to_map([6.0, 4.5], yaw=yaw), [6.0, 4.5])
    turned = apartment_to_map(table, yaw=yaw)
    assert math.dist(turned, (6.0, 4.5)) == pytest.approx(math.dist(table, (6.0, 4.5)))


def test_apartment_noise_is_deterministic_and_looks_like_slam():
    clean = apartment_grid()
    noisy = apartment_grid(noise=0.3, seed=4)
    np.testing.assert_array_equal(noisy.cells, apartment_grid(noise=0.3, seed=4).cells)
    assert not np.array_equal(noisy.cells, apartment_grid(noise=0.3, seed=5).cells)
    np.testing.assert_array_equal(apartment_grid(seed=9).cells, clean.cells)  # no noise, no draw
    assert np.all(noisy.cells[clean.cells == OCCUPIED] == OCCUPIED)  # walls only grow
    grown = (noisy.cells == OCCUPIED) & (clean.cells == FREE)
    specks = (noisy.cells == UNKNOWN) & (clean.cells == FREE)
    assert 200 < grown.sum() < 3000 and 10 < specks.sum() < 400
    labels, _ = ndimage.label(noisy.cells == FREE)
    sizes = np.bincount(labels.ravel())[1:]
    assert sizes.max() >= 0.995 * sizes.sum()  # islands of a few cells at most
    ix, iy = noisy.cell_of(apartment_to_map([centre(r) for r in APARTMENT_ROOMS.values()]))
    assert len(set(labels[iy, ix].tolist())) == 1 and labels[iy[0], ix[0]] == np.argmax(sizes) + 1
    with pytest.raises(ConfigError, match="noise"):
        apartment_grid(noise=1.5)


@pytest.mark.parametrize(("width", "cells"), [(0.40, 8), (0.42, 8), (0.45, 8), (0.50, 10), (0.1, 2)])
def test_corridor_is_never_wider_on_the_grid(width, cells):
    grid = corridor_grid(width)
    ix, _ = grid.cell_of([[3.5, 1.5]])  # in the corridor, between the rooms
    column = grid.cells[:, ix[0]]
    assert (column == FREE).sum() == cells and cells * grid.resolution <= width + 1e-9
    assert ndimage.label(grid.cells == FREE)[1] == 1
    ix, iy = grid.cell_of([[1.5, 1.5], [5.5, 1.5]])  # both room centres
    assert np.all(grid.cells[iy, ix] == FREE)
    with pytest.raises(ConfigError, match="width_m"):
        corridor_grid(0.0)


def test_draw_apartment_map_script(tmp_path):
    script = load_script("draw_apartment_map")
    main = script.main
    assert main(["--out", str(tmp_path), "--noise", "0", "--yaw", "90"]) == 0
    ros_map = read_ros_map(tmp_path / "map.yaml")
    expected = apartment_grid(yaw=math.pi / 2)
    np.testing.assert_array_equal(ros_map.grid.cells, expected.cells)
    np.testing.assert_allclose(ros_map.grid.origin, expected.origin)
    assert ros_map.grid.yaw == pytest.approx(math.pi / 2)
    assert main(["--out", str(tmp_path), "--noise", "2"]) == 2
