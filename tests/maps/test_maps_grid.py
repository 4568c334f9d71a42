"""Grid map loaders: ROS map_server (YAML + PGM/PNG) and Moving AI (.map/.scen).

Facts are read independently of the loaders: the PGM/map/scen bytes are parsed here in a few lines,
hand-made images are written here (PGM, and PNG with a minimal encoder), and the cell statistics are
read from the SOURCE.md tables. Tolerances: positions 1e-9 m (exact arithmetic up to rounding);
cell percentages 0.1 percentage point (SOURCE.md rounds to 0.1); lookups at pixel centres and at
points up to 0.45 cell from them.
"""

from __future__ import annotations

import math
import re
import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from nhstab.errors import InputError, PipelineError
from nhstab.maps.base import Map, MapError
from nhstab.maps.movingai import (
    load_movingai_map,
    load_movingai_scenarios,
    movingai_cell_to_world,
    world_to_movingai_cell,
)
from nhstab.maps.ros import load_ros_map, map_server_values, read_image

MAPS = Path(__file__).resolve().parents[2] / "maps"
NAV2 = MAPS / "nav2"
MOVINGAI = MAPS / "movingai"
ROOM_MAP = MOVINGAI / "64room_000.map"
ROOM_SCEN = MOVINGAI / "64room_000.map.scen"
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# --------------------------------------------------------------------------------------------------
# Independent helpers


def parse_pgm(data: bytes) -> np.ndarray:
    """Minimal binary 8-bit PGM parser (header tokens may be separated by comments)."""
    tokens, pos = [], 0
    token = re.compile(rb"(?:\s|#[^\n]*\n)*(\S+)")
    while len(tokens) < 4:
        m = token.match(data, pos)
        tokens.append(m.group(1))
        pos = m.end()
    assert tokens[0] == b"P5" and tokens[3] == b"255"
    w, h = int(tokens[1]), int(tokens[2])
    return np.frombuffer(data[pos + 1:pos + 1 + w * h], dtype=np.uint8).reshape(h, w)


def write_pgm(path: Path, pixels, maxval: int = 255, plain: bool = False, comment: str = "") -> Path:
    pixels = np.asarray(pixels)
    h, w = pixels.shape
    c = f"# {comment}\n" if comment else ""
    if plain:
        body = "\n".join(" ".join(str(int(v)) for v in row) for row in pixels)
        path.write_bytes(f"P2\n{c}{w} {h}\n{c}{maxval}\n{body}\n".encode())
    else:
        dtype = np.uint8 if maxval < 256 else ">u2"
        path.write_bytes(f"P5\n{c}{w} {h}\n{maxval}\n".encode() + pixels.astype(dtype).tobytes())
    return path


def write_png(path: Path, pixels, colour_type: int) -> Path:
    """Minimal 8-bit PNG encoder: colour_type 0 grey, 2 RGB, 4 grey+alpha, 6 RGBA."""
    pixels = np.asarray(pixels, dtype=np.uint8)
    h, w = pixels.shape[:2]
    raw = b"".join(b"\x00" + pixels[r].tobytes() for r in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))
    return path


def write_yaml(path: Path, image: str, **overrides) -> Path:
    doc = {"image": image, "resolution": 0.25, "origin": [0.0, 0.0, 0.0], "negate": 0,
           "occupied_thresh": 0.65, "free_thresh": 0.25}
    doc.update(overrides)
    doc = {k: v for k, v in doc.items() if v is not None}
    path.write_text(yaml.safe_dump(doc))
    return path


def state_at(m: Map, x: float, y: float) -> str:
    """'occupied' / 'free' / 'unknown' of the loaded grid at world point (x, y)."""
    grid = m.grids[0]
    i, j = grid.world_to_cell(x, y)
    assert 0 <= i < grid.shape[0] and 0 <= j < grid.shape[1], (x, y, i, j)
    if grid.unknown is not None and grid.unknown[i, j]:
        return "unknown"
    return "occupied" if grid.occupied[i, j] else "free"


def assert_map_error(excinfo, *names: Path) -> None:
    err = excinfo.value
    assert isinstance(err, MapError) and isinstance(err, PipelineError)
    text = str(err)
    assert "\n" not in text, text
    for name in names:
        assert str(name) in text, (str(name), text)


# --------------------------------------------------------------------------------------------------
# ROS: the nav2 maps against their own bytes and SOURCE.md


NAV2_NAMES = ["depot", "tb3_sandbox", "smoothers_world"]


@pytest.mark.parametrize("name", NAV2_NAMES)
def test_nav2_map_matches_pixels_read_directly(name):
    meta = yaml.safe_load((NAV2 / f"{name}.yaml").read_text())
    pixels = parse_pgm((NAV2 / meta["image"]).read_bytes())
    h, w = pixels.shape
    res, (ox, oy, yaw) = meta["resolution"], meta["origin"]
    assert yaw == 0
    m = load_ros_map(NAV2 / f"{name}.yaml")
    assert m.name == name and m.source == str(NAV2 / f"{name}.yaml") and len(m.grids) == 1
    assert m.grids[0].shape == (h, w)

    rng = np.random.default_rng(7)
    rows, cols = rng.integers(0, h, 300), rng.integers(0, w, 300)
    # plus the first pixel of every distinct value (occupied 0, free 254/255, unknown 205, greys)
    for v in np.unique(pixels):
        r, c = np.argwhere(pixels == v)[0]
        rows, cols = np.append(rows, r), np.append(cols, c)
    for r, c in zip(rows, cols):
        p = (255 - int(pixels[r, c])) / 255
        expected = "occupied" if p > meta["occupied_thresh"] else "free" if p < meta["free_thresh"] else "unknown"
        x = ox + (c + 0.5) * res            # PGM row 0 is the top (largest y)
        y = oy + (h - 1 - r + 0.5) * res
        for dx, dy in [(0, 0), (0.45, 0.45), (-0.45, -0.45), (0.45, -0.45)]:
            assert state_at(m, x + dx * res, y + dy * res) == expected, (name, r, c, pixels[r, c])


@pytest.mark.parametrize("name", NAV2_NAMES)
def test_nav2_cell_counts_match_source_md(name):
    table = (NAV2 / "SOURCE.md").read_text()
    row = re.search(rf"^\| {name} \| (\d+) × (\d+) \| ([\d.]+) m \| ([\d.]+) × ([\d.]+) m \|.*\| "
                    r"([\d.]+) % / ([\d.]+) % / ([\d.]+) % \|$", table, re.M)
    assert row, name
    w, h = int(row[1]), int(row[2])
    size_x, size_y = float(row[4]), float(row[5])
    pct = [float(row[k]) for k in (6, 7, 8)]
    m = load_ros_map(NAV2 / f"{name}.yaml")
    assert (m.meta["width"], m.meta["height"]) == (w, h)
    assert m.meta["resolution"] == pytest.approx(float(row[3]), abs=1e-12)
    assert m.size == pytest.approx((size_x, size_y), abs=1e-9)
    cells = m.meta["cells"]
    got = [100 * cells[k] / (w * h) for k in ("occupied", "free", "unknown")]
    assert got == pytest.approx(pct, abs=0.1)
    assert cells["intermediate"] == 0
    assert cells["occupied"] + cells["free"] + cells["unknown"] == w * h


def test_tb3_sandbox_origin_and_unknown_policies():
    strict = load_ros_map(NAV2 / "tb3_sandbox.yaml")
    lenient = load_ros_map(NAV2 / "tb3_sandbox.yaml", unknown="free")
    assert strict.bounds == pytest.approx((-10.0, -10.0, -10.0 + 19.2, -10.0 + 19.2), abs=1e-9)
    gs, gl = strict.grids[0], lenient.grids[0]
    assert np.array_equal(gs.unknown, gl.unknown) and gs.unknown.mean() > 0.9
    assert np.array_equal(gs.occupied, gl.occupied | gl.unknown)
    assert not np.any(gl.occupied & gl.unknown)
    assert strict.meta["unknown_policy"] == "occupied" and lenient.meta["unknown_policy"] == "free"


def test_bad_unknown_policy_is_an_input_error():
    with pytest.raises(InputError) as excinfo:
        load_ros_map(NAV2 / "depot.yaml", unknown="maybe")
    assert excinfo.value.argument == "unknown"


def test_depot_loads_fast_and_plain_and_png_copies_agree(tmp_path):
    ref = load_ros_map(NAV2 / "depot.yaml")
    pixels = parse_pgm((NAV2 / "depot.pgm").read_bytes())
    write_pgm(tmp_path / "plain.pgm", pixels, plain=True, comment="plain copy")
    write_png(tmp_path / "depot.png", pixels, colour_type=0)
    for image in ("plain.pgm", "depot.png"):
        m = load_ros_map(write_yaml(tmp_path / f"{image}.yaml", image, resolution=0.05))
        assert np.array_equal(m.grids[0].occupied, ref.grids[0].occupied), image
        assert np.array_equal(m.grids[0].unknown, ref.grids[0].unknown), image


# --------------------------------------------------------------------------------------------------
# ROS: hand-made images whose answer is known by construction

# 3 x 2 image, negate 1 so p = v / 255: 255 occupied, 0 free, 128 (p = 0.502) unknown.
TINY = np.array([[255, 0, 0],      # top row (largest y); the occupied pixel is the top-left one
                 [0, 128, 0]])     # bottom row; the unknown pixel is in the middle


@pytest.mark.parametrize("yaw", [0.0, math.pi / 2])
def test_handmade_origin_yaw_resolution_negate(tmp_path, yaw):
    write_pgm(tmp_path / "tiny.pgm", TINY, comment="hand made")
    m = load_ros_map(write_yaml(tmp_path / "tiny.yaml", "tiny.pgm", resolution=0.25,
                                origin=[1.5, -2.0, yaw], negate=1))
    ox, oy = 1.5, -2.0                    # resolution 0.25 m
    # Pixel (row r, col c) centre in the grid frame: u = (c + .5) res, v = (H - 1 - r + .5) res.
    # yaw 0: world = origin + (u, v); yaw pi/2: world = origin + (-v, u).
    if yaw == 0.0:
        expect = {(0, 0): (ox + 0.125, oy + 0.375), (1, 1): (ox + 0.375, oy + 0.125), (0, 2): (ox + 0.625, oy + 0.375)}
        bounds = (1.5, -2.0, 1.5 + 0.75, -2.0 + 0.5)
    else:
        expect = {(0, 0): (ox - 0.375, oy + 0.125), (1, 1): (ox - 0.125, oy + 0.375), (0, 2): (ox - 0.375, oy + 0.625)}
        bounds = (1.5 - 0.5, -2.0, 1.5, -2.0 + 0.75)
    assert m.bounds == pytest.approx(bounds, abs=1e-9)
    assert state_at(m, *expect[(0, 0)]) == "occupied"
    assert state_at(m, *expect[(1, 1)]) == "unknown"
    assert state_at(m, *expect[(0, 2)]) == "free"
    grid = m.grids[0]
    assert grid.cell_to_world(1, 0) == pytest.approx(expect[(0, 0)], abs=1e-9)     # image row 0 = grid row 1
    assert grid.occupied.sum() == 2 and grid.unknown.sum() == 1                       # unknown counts as occupied
    assert m.meta["cells"] == {"occupied": 1, "free": 4, "unknown": 1, "intermediate": 0}
    assert m.meta["negate"] is True and m.meta["origin"] == pytest.approx([1.5, -2.0, yaw])
    assert m.name == "tiny" and m.source == str(tmp_path / "tiny.yaml")


# One row of grey values and, for thresholds occupied 0.65 / free 0.25 and p = (255 - v)/255, the
# ROS values map_server publishes (worked by hand):
#   v       0     89     90     100    128    191    192    254    255
#   p       1     .651   .647   .608   .498   .251   .247   .004   0
#   trinary 100   100    -1     -1     -1     -1     0      0      0
#   scale   100   100    99     89     62     0      0      0      0     rint((p - .25) / .4 * 100)
#   raw     0     89     90     100    -1     -1     -1     -1     -1    the pixel value if <= 100
MODES_ROW = [0, 89, 90, 100, 128, 191, 192, 254, 255]
EXPECTED_VALUES = {
    "trinary": [100, 100, -1, -1, -1, -1, 0, 0, 0],
    "scale": [100, 100, 99, 89, 62, 0, 0, 0, 0],
    "raw": [0, 89, 90, 100, -1, -1, -1, -1, -1],
}


@pytest.mark.parametrize("mode", ["trinary", "scale", "raw"])
@pytest.mark.parametrize("policy", ["occupied", "free"])
def test_modes_and_unknown_policies(tmp_path, mode, policy):
    write_pgm(tmp_path / "row.pgm", [MODES_ROW])
    expected = np.array(EXPECTED_VALUES[mode])
    image = read_image(tmp_path / "row.pgm")
    assert map_server_values(image, mode, False, 0.65, 0.25)[0].tolist() == expected.tolist()
    if mode == "raw":   # raw ignores negate and thresholds
        assert map_server_values(image, mode, True, 0.1, 0.05)[0].tolist() == expected.tolist()
    m = load_ros_map(write_yaml(tmp_path / "row.yaml", "row.pgm", mode=mode), unknown=policy)
    grid = m.grids[0]
    unknown_like = (expected == -1) | ((expected > 0) & (expected < 100))
    assert grid.unknown[0].tolist() == unknown_like.tolist()
    occupied = (expected == 100) | (unknown_like if policy == "occupied" else False)
    assert grid.occupied[0].tolist() == occupied.tolist()
    intermediate = int(((expected > 0) & (expected < 100)).sum())
    assert m.meta["cells"] == {"occupied": int((expected == 100).sum()), "free": int((expected == 0).sum()),
                               "unknown": int(unknown_like.sum()), "intermediate": intermediate}
    assert m.meta["mode"] == mode


def test_mode_is_case_insensitive_and_defaults_to_trinary(tmp_path):
    write_pgm(tmp_path / "row.pgm", [MODES_ROW])
    a = load_ros_map(write_yaml(tmp_path / "a.yaml", "row.pgm", mode="Scale"))
    b = load_ros_map(write_yaml(tmp_path / "b.yaml", "row.pgm"))
    assert a.meta["mode"] == "scale" and b.meta["mode"] == "trinary"


# RGBA pixels: white opaque, white alpha 254, white alpha 0, black alpha 0, red opaque.
# trinary averages alpha in as a 4th channel (map_server: "average in alpha with color channels"):
#   shade = (R + G + B + A) / 1020:  1, .999, .75, 0, .5  ->  p = 0, .001, .25, 1, .5
#   with occupied .65 / free .196:   free, free, unknown, occupied, unknown
# scale: any pixel that is not fully opaque is unknown; red opaque: shade 1/3, p = .667 -> occupied.
# raw: round(mean(R, G, B)): 255, 255, 255, 0, 85 -> -1, -1, -1, 0, 85.
RGBA_ROW = [[255, 255, 255, 255], [255, 255, 255, 254], [255, 255, 255, 0], [0, 0, 0, 0], [255, 0, 0, 255]]


@pytest.mark.parametrize("mode,expected", [
    ("trinary", [0, 0, -1, 100, -1]),
    ("scale", [0, -1, -1, -1, 100]),
    ("raw", [-1, -1, -1, 0, 85]),
])
def test_png_alpha_and_colour(tmp_path, mode, expected):
    write_png(tmp_path / "rgba.png", [RGBA_ROW], colour_type=6)
    values = map_server_values(read_image(tmp_path / "rgba.png"), mode, False, 0.65, 0.196)
    assert values[0].tolist() == expected
    m = load_ros_map(write_yaml(tmp_path / "rgba.yaml", "rgba.png", mode=mode, free_thresh=0.196))
    assert m.grids[0].unknown[0].tolist() == [v not in (0, 100) for v in expected]


def test_colour_averaging_and_grey_alpha(tmp_path):
    # RGB without alpha: red shade 1/3 (p .667, occupied); cyan shade 2/3 (p .333, unknown); grey 250 free
    write_png(tmp_path / "rgb.png", [[[255, 0, 0], [0, 255, 255], [250, 250, 250]]], colour_type=2)
    assert map_server_values(read_image(tmp_path / "rgb.png"))[0].tolist() == [100, -1, 0]
    # grey + alpha: white transparent (p .25 -> unknown with free .196), white opaque (free)
    write_png(tmp_path / "la.png", [[[255, 0], [255, 255]]], colour_type=4)
    assert map_server_values(read_image(tmp_path / "la.png"), "trinary", False, 0.65, 0.196)[0].tolist() == [-1, 0]
    assert map_server_values(read_image(tmp_path / "la.png"), "scale", False, 0.65, 0.196)[0].tolist() == [-1, 0]
    # PPM P6 colour: red occupied, white free
    (tmp_path / "c.ppm").write_bytes(b"P6\n2 1\n255\n" + bytes([255, 0, 0, 255, 255, 255]))
    assert map_server_values(read_image(tmp_path / "c.ppm"))[0].tolist() == [100, 0]


def test_16bit_and_plain_pgm_with_other_maxval(tmp_path):
    write_pgm(tmp_path / "w.pgm", [[0, 65535, 30000]], maxval=65535)        # p = 1, 0, .542
    assert map_server_values(read_image(tmp_path / "w.pgm"))[0].tolist() == [100, 0, -1]
    write_pgm(tmp_path / "p.pgm", [[0, 15, 8]], maxval=15, plain=True, comment="maxval 15")  # p = 1, 0, .467
    assert map_server_values(read_image(tmp_path / "p.pgm"))[0].tolist() == [100, 0, -1]


# --------------------------------------------------------------------------------------------------
# ROS: malformed inputs


def _good(tmp_path: Path) -> Path:
    write_pgm(tmp_path / "img.pgm", TINY)
    return tmp_path / "img.pgm"


BAD_YAML = {
    "unknown key": "image: img.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
                   "free_thresh: 0.25\nfoo: 1\n",
    "negative resolution": "image: img.pgm\nresolution: -0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
                           "free_thresh: 0.25\n",
    "zero resolution": "image: img.pgm\nresolution: 0\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
                       "free_thresh: 0.25\n",
    "NaN resolution": "image: img.pgm\nresolution: .nan\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
                      "free_thresh: 0.25\n",
    "NaN origin": "image: img.pgm\nresolution: 0.1\norigin: [0, .nan, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
                  "free_thresh: 0.25\n",
    "inf threshold": "image: img.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: .inf\n"
                     "free_thresh: 0.25\n",
    "missing key": "image: img.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n",
    "wrong type": "image: img.pgm\nresolution: fine\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
                  "free_thresh: 0.25\n",
    "short origin": "image: img.pgm\nresolution: 0.1\norigin: [0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
                    "free_thresh: 0.25\n",
    "negate 2": "image: img.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 2\noccupied_thresh: 0.65\n"
                "free_thresh: 0.25\n",
    "bad mode": "image: img.pgm\nmode: binary\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
                "occupied_thresh: 0.65\nfree_thresh: 0.25\n",
    "threshold > 1": "image: img.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 1.5\n"
                     "free_thresh: 0.25\n",
    "free > occupied": "image: img.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.3\n"
                       "free_thresh: 0.5\n",
    "syntax error": "image: img.pgm\nresolution: [0.1\n",
    "not a mapping": "- image\n- img.pgm\n",
    "empty": "",
}


@pytest.mark.parametrize("case", sorted(BAD_YAML))
def test_bad_yaml_gives_one_line_map_error_naming_the_file(tmp_path, case):
    _good(tmp_path)
    path = tmp_path / "bad.yaml"
    path.write_text(BAD_YAML[case])
    with pytest.raises(MapError) as excinfo:
        load_ros_map(path)
    assert_map_error(excinfo, path)
    if case == "unknown key":
        assert "foo" in str(excinfo.value)


def test_numbers_as_yaml_cpp_reads_them(tmp_path):
    _good(tmp_path)
    # PyYAML leaves 5e-2 as a string; yaml-cpp (map_server) reads it as a number
    path = tmp_path / "exp.yaml"
    path.write_text("image: img.pgm\nresolution: 5e-2\norigin: [0, 0, 0]\nnegate: false\n"
                    "occupied_thresh: 0.65\nfree_thresh: 0.25\n")
    assert load_ros_map(path).meta["resolution"] == 0.05


BAD_IMAGES = {
    "missing image": None,
    "not an image": b"this is not an image at all",
    "truncated PGM": "truncated",
    "value above maxval": b"P5\n2 1\n100\n\x00\xff",
    "bad header": b"P5\n2 x\n255\n\x00\x00",
    "zero width": b"P5\n0 1\n255\n",
    "PNG cut inside IDAT": -40,
    "PNG without IEND": -12,
    "PNG with a bad checksum": "crc",
}


@pytest.mark.parametrize("case", sorted(BAD_IMAGES))
def test_bad_image_gives_map_error_naming_both_files(tmp_path, case):
    content = BAD_IMAGES[case]
    image = tmp_path / "img.pgm"
    if content == "truncated":
        content = (NAV2 / "depot.pgm").read_bytes()[:5000]
    elif isinstance(content, int) or content == "crc":
        noise = np.random.default_rng(3).integers(0, 256, (40, 40))
        full = write_png(tmp_path / "full.png", noise, 0).read_bytes()
        image = tmp_path / "img.png"
        content = full[:content] if isinstance(content, int) else full[:50] + bytes([full[50] ^ 1]) + full[51:]
    if content is not None:
        image.write_bytes(content)
    path = write_yaml(tmp_path / "m.yaml", image.name)
    with pytest.raises(MapError) as excinfo:
        load_ros_map(path)
    assert_map_error(excinfo, image, path)


def test_missing_yaml(tmp_path):
    with pytest.raises(MapError) as excinfo:
        load_ros_map(tmp_path / "nowhere.yaml")
    assert_map_error(excinfo, tmp_path / "nowhere.yaml")


# --------------------------------------------------------------------------------------------------
# Moving AI


def room_text_rows() -> list[str]:
    lines = ROOM_MAP.read_text().splitlines()
    h, w = int(lines[1].split()[1]), int(lines[2].split()[1])
    rows = lines[4:4 + h]
    assert len(rows) == h and all(len(r) == w for r in rows)
    return rows


def test_movingai_scenarios_start_and_goal_cells_are_free():
    rows = room_text_rows()
    h = len(rows)
    cs = 0.5
    m = load_movingai_map(ROOM_MAP, cell_size=cs)
    problems = load_movingai_scenarios(ROOM_SCEN, cell_size=cs)
    raw = [line.split("\t") for line in ROOM_SCEN.read_text().splitlines()[1:]]
    assert len(problems) == len(raw)
    for k in range(0, len(raw), 41):                   # 50 scenarios spread over all buckets
        bucket, _, _, height, sx, sy, gx, gy, opt = raw[k]
        sx, sy, gx, gy, height = int(sx), int(sy), int(gx), int(gy), int(height)
        assert height == h
        assert rows[sy][sx] == "." and rows[gy][gx] == "."        # read from the text directly
        p = problems[k]
        start = ((sx + 0.5) * cs, (h - 1 - sy + 0.5) * cs)
        goal = ((gx + 0.5) * cs, (h - 1 - gy + 0.5) * cs)
        assert (p.start.x, p.start.y) == pytest.approx(start, abs=1e-9)
        assert (p.goal.x, p.goal.y) == pytest.approx(goal, abs=1e-9)
        heading = math.atan2(goal[1] - start[1], goal[0] - start[0])
        assert p.start.theta == pytest.approx(heading, abs=1e-12) and p.goal.theta == pytest.approx(heading, abs=1e-12)
        assert p.reference_length == pytest.approx(float(opt) * cs, rel=1e-12)
        assert p.label == f"bucket {bucket} #{k}"
        assert state_at(m, p.start.x, p.start.y) == "free" and state_at(m, p.goal.x, p.goal.y) == "free"


def test_movingai_map_matches_text_and_source_md():
    rows = room_text_rows()
    chars = np.array([list(r) for r in rows])
    m = load_movingai_map(ROOM_MAP, cell_size=0.25)
    grid = m.grids[0]
    assert grid.shape == (512, 512) and m.bounds == pytest.approx((0, 0, 128, 128), abs=1e-9)
    assert np.array_equal(grid.occupied, np.flipud(chars != "."))   # this map has no 'G'
    assert m.name == "64room_000" and m.problems == ()
    source = (MOVINGAI / "SOURCE.md").read_text()
    pct = {c: float(re.search(rf"([\d.]+) % '{re.escape(c)}'", source)[1]) for c in ".@T"}
    for c, expected in pct.items():
        assert 100 * m.meta["characters"][c] / 512 ** 2 == pytest.approx(expected, abs=0.1)
    problems = load_movingai_scenarios(ROOM_SCEN)
    n_scen, n_buckets = (int(v) for v in re.search(r"(\d+) scenarios in (\d+) buckets", source).groups())
    assert len(problems) == n_scen
    assert len({p.label.split(" #")[0] for p in problems}) == n_buckets
    longest = float(re.search(r"maximum optimal length (\d+(?:\.\d+)?)", source)[1])
    assert max(p.reference_length for p in problems) == pytest.approx(longest, abs=0.05)


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_movingai_orientation_and_characters(tmp_path, newline):
    text = newline.join(["type octile", "width 3", "height 2", "map", "@.G", "TSW"]) + newline
    path = tmp_path / "tiny.map"
    path.write_text(text, newline="")
    m = load_movingai_map(path, cell_size=2.0)
    # text row 0 (top) is at y in [2, 4]; only '.' and 'G' are free
    assert [state_at(m, x, 3.0) for x in (1.0, 3.0, 5.0)] == ["occupied", "free", "free"]
    assert [state_at(m, x, 1.0) for x in (1.0, 3.0, 5.0)] == ["occupied"] * 3
    assert m.meta["cells"] == {"free": 2, "blocked": 4} and m.meta["cell_size"] == 2.0
    assert m.bounds == (0.0, 0.0, 6.0, 4.0)


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.data(),
       st.floats(0.01, 100.0, allow_nan=False, allow_infinity=False))
def test_movingai_world_cell_round_trip(width, height, data, cell_size):
    x = data.draw(st.integers(0, width - 1))
    y = data.draw(st.integers(0, height - 1))
    wx, wy = movingai_cell_to_world(x, y, height, cell_size)
    assert tuple(int(v) for v in world_to_movingai_cell(wx, wy, height, cell_size)) == (x, y)
    # same answer through the loaded grid
    grid = _free_grid(width, height, cell_size)
    i, j = grid.world_to_cell(wx, wy)
    assert (int(i), int(j)) == (height - 1 - y, x)
    assert grid.cell_to_world(i, j) == pytest.approx((float(wx), float(wy)), abs=1e-9 * max(1.0, cell_size))


def _free_grid(width: int, height: int, cell_size: float):
    """The grid of an all-free Moving AI map of the given size (hypothesis forbids tmp_path here)."""
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "t.map"
        p.write_text(f"type octile\nheight {height}\nwidth {width}\nmap\n" + ("." * width + "\n") * height)
        return load_movingai_map(p, cell_size).grids[0]


GOOD_MAP = "type octile\nheight 2\nwidth 3\nmap\n...\n.@.\n"
BAD_MAPS = {   # text -> line the error must name
    "type grid\nheight 2\nwidth 3\nmap\n...\n...\n": 1,
    "type octile\nheight two\nwidth 3\nmap\n...\n...\n": 2,
    "type octile\nheight 2\nheight 3\nmap\n...\n...\n": 3,
    "type octile\nheight 2\nwidth 3\nmaps\n...\n...\n": 4,
    "type octile\nheight 2\nwidth 3\nmap\n...\n..\n": 6,
    "type octile\nheight 2\nwidth 3\nmap\n...\n": 6,
    "type octile\nheight 2\nwidth 3\nmap\n...\n...\n...\n": 7,
    "type octile\nheight 2\nwidth 3\nmap\n...\n.\t.\n": 6,
    "type octile\nheight 2\nwidth 3\nmap\n...\n.\u00e9.\n": 6,
    "type octile\nheight 0\nwidth 3\nmap\n": 2,
    "type octile\n": 2,
}


@pytest.mark.parametrize("text", sorted(BAD_MAPS))
def test_bad_movingai_maps(tmp_path, text):
    path = tmp_path / "bad.map"
    path.write_bytes(text.encode("utf-8"))
    with pytest.raises(MapError) as excinfo:
        load_movingai_map(path)
    assert_map_error(excinfo, path)
    assert f"{path}:{BAD_MAPS[text]}'" in str(excinfo.value)


SCEN_LINE = "0\tx.map\t3\t2\t0\t0\t2\t1\t2.41421\n"
BAD_SCENS = {
    "version 2\n" + SCEN_LINE: 1,
    "version 1\n" + SCEN_LINE.replace("\t2.41421", ""): 2,
    "version 1\n" + SCEN_LINE + SCEN_LINE.replace("\t0\t0\t", "\t0\tzero\t"): 3,
    "version 1\n" + SCEN_LINE.replace("2.41421", "nan"): 2,
    "version 1\n" + SCEN_LINE.replace("2.41421", "inf"): 2,
    "version 1\n" + SCEN_LINE.replace("2.41421", "-1"): 2,
    "version 1\n" + SCEN_LINE.replace("\t2\t1\t", "\t3\t1\t"): 2,      # goal_x outside width 3
    "version 1\n" + SCEN_LINE.replace("\t2\t1\t", "\t2\t2\t"): 2,      # goal_y outside height 2
    "version 1\n" + SCEN_LINE.replace("\t3\t2\t", "\t3\t0\t"): 2,
}


@pytest.mark.parametrize("text", sorted(BAD_SCENS))
def test_bad_movingai_scenarios(tmp_path, text):
    path = tmp_path / "bad.scen"
    path.write_text(text)
    with pytest.raises(MapError) as excinfo:
        load_movingai_scenarios(path)
    assert_map_error(excinfo, path)
    assert f"{path}:{BAD_SCENS[text]}'" in str(excinfo.value)


def test_scenarios_version_1_0_map_height_and_cell_size(tmp_path):
    path = tmp_path / "ok.scen"
    path.write_text("version 1.0\r\n" + SCEN_LINE.replace("\n", "\r\n"))
    (p,) = load_movingai_scenarios(path, cell_size=2.0, map_height=2)
    assert (p.start.x, p.start.y, p.goal.x, p.goal.y) == (1.0, 3.0, 5.0, 1.0)
    assert p.start.theta == pytest.approx(math.atan2(-2.0, 4.0)) and p.reference_length == pytest.approx(4.82842)
    with pytest.raises(MapError) as excinfo:
        load_movingai_scenarios(path, map_height=5)                 # disagrees with the height field
    assert_map_error(excinfo, path)
    map_path = tmp_path / "ok.map"
    map_path.write_text(GOOD_MAP)
    for bad in (0.0, -1.0, math.nan, math.inf, "1"):
        for call in (lambda: load_movingai_map(map_path, cell_size=bad),
                     lambda: load_movingai_scenarios(path, cell_size=bad)):
            with pytest.raises(MapError) as excinfo:
                call()
            assert excinfo.value.argument == "cell_size"
    with pytest.raises(MapError) as excinfo:
        load_movingai_map(tmp_path / "missing.map")
    assert_map_error(excinfo, tmp_path / "missing.map")


# --------------------------------------------------------------------------------------------------
# Fuzzing: only PipelineErrors, never another exception


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def _only_pipeline_errors(call):
    try:
        return call()
    except PipelineError:
        return None


MAPISH = st.builds(
    lambda head, h, w, rows, tail: f"{head}\nheight {h}\nwidth {w}\nmap\n" + "\n".join(rows) + tail,
    st.sampled_from(["type octile", "type  octile", "type octal"]),
    st.sampled_from(["2", "3", "-1", "x", "99999999999999999999"]), st.sampled_from(["2", "3", "0"]),
    st.lists(st.text(alphabet=".@GTSW \t\r\u00e9", min_size=0, max_size=4), max_size=4),
    st.sampled_from(["", "\n", "\n\n", "\nextra"]),
)


@FUZZ
@given(text=st.one_of(st.text(max_size=200), MAPISH))
def test_fuzz_movingai_text(fuzz_dir, text):
    path = fuzz_dir / "f.map"
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    _only_pipeline_errors(lambda: load_movingai_map(path))
    scen = fuzz_dir / "f.scen"
    scen.write_bytes(("version 1\n" + text).encode("utf-8", "surrogatepass"))
    _only_pipeline_errors(lambda: load_movingai_scenarios(scen))


@FUZZ
@given(fraction=st.floats(0, 1))
def test_fuzz_truncated_real_files(fuzz_dir, fraction):
    data = ROOM_MAP.read_bytes()
    n = int(fraction * len(data))
    path = fuzz_dir / "t.map"
    path.write_bytes(data[:n])
    if n < len(data) - 1:           # only dropping the final newline keeps the map valid
        with pytest.raises(MapError):
            load_movingai_map(path)
    else:
        load_movingai_map(path)
    scen_data = ROOM_SCEN.read_bytes()
    scen = fuzz_dir / "t.scen"
    scen.write_bytes(scen_data[:int(fraction * len(scen_data))])
    _only_pipeline_errors(lambda: load_movingai_scenarios(scen))
    pgm = (NAV2 / "tb3_sandbox.pgm").read_bytes()
    k = int(fraction * len(pgm))
    (fuzz_dir / "t.pgm").write_bytes(pgm[:k])
    yml = write_yaml(fuzz_dir / "t.yaml", "t.pgm")
    if k < len(pgm):
        with pytest.raises(MapError):
            load_ros_map(yml)


YAML_SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-3, 300), st.floats(allow_nan=True),
                         st.text(max_size=12), st.sampled_from(["trinary", "scale", "raw", "t.pgm", "junk.bin"]))
YAML_VALUES = st.recursive(YAML_SCALARS, lambda inner: st.lists(inner, max_size=4), max_leaves=6)
YAML_KEYS = st.sampled_from(["image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh",
                             "mode", "extra"])


@FUZZ
@given(text=st.text(max_size=300))
def test_fuzz_ros_yaml_text(fuzz_dir, text):
    path = fuzz_dir / "r.yaml"
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    _only_pipeline_errors(lambda: load_ros_map(path))


@FUZZ
@given(doc=st.dictionaries(YAML_KEYS, YAML_VALUES, max_size=8),
       base=st.fixed_dictionaries({"image": st.sampled_from(["t.pgm", "junk.bin", "none.pgm"]),
                                   "resolution": st.sampled_from([0.05, 1, -1, "0.1"]),
                                   "origin": st.sampled_from([[0, 0, 0], [1.5, -2, 3.14], [0, 0]]),
                                   "negate": st.sampled_from([0, 1, True]),
                                   "occupied_thresh": st.sampled_from([0.65, 0.2]),
                                   "free_thresh": st.sampled_from([0.196, 0.3])}),
       junk=st.binary(max_size=64))
def test_fuzz_ros_yaml_structured(fuzz_dir, doc, base, junk):
    write_pgm(fuzz_dir / "t.pgm", TINY)
    (fuzz_dir / "junk.bin").write_bytes(junk)
    merged = {**base, **doc}
    path = fuzz_dir / "s.yaml"
    path.write_text(yaml.safe_dump(merged))
    m = _only_pipeline_errors(lambda: load_ros_map(path, unknown="free"))
    if m is not None:
        assert m.grids[0].shape == (2, 3) or m.meta["image"].endswith("junk.bin")
