"""Vector maps: Bench-MR SVG worlds, nhstab's YAML map format, the load_map entry point, our maps.

Reference values for the Bench-MR worlds come from ``maps/bench-mr/SOURCE.md`` (measured there
independently of this loader); geometric checks use shapely, an implementation independent of
``nhstab.maps``. Tolerances are stated at each comparison.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import shapely.geometry as sg
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from nhstab.errors import InputError, PipelineError
from nhstab.geometry import is_simple_polygon, point_in_polygon
from nhstab.maps import Circle, Map, MapError, Polygon, load_map
from nhstab.maps.svg import (
    BENCHMR_SCALE,
    load_benchmr_footprint,
    load_benchmr_scenarios,
    load_benchmr_svg,
    parse_path_d,
)
from nhstab.maps.yaml_format import load_yaml_map

MAPS = Path(__file__).resolve().parents[2] / "maps"
MAZES = MAPS / "bench-mr" / "polygon_mazes"
OURS = MAPS / "ours"
OUR_MAPS = ("parking_lot", "warehouse_corridor", "cluttered_room")

# SOURCE.md table: polygons, x range, y range (2 decimals)
BENCHMR_TABLE = {
    "parking1": (13, (-1.37, 17.28), (-9.65, 4.75)),
    "parking2": (16, (-1.37, 17.94), (-9.57, 4.74)),
    "parking3": (19, (-9.01, 27.59), (-17.24, 9.45)),
    "warehouse": (88, (-11.10, 74.61), (-68.28, 12.16)),
}
RANGE_TOL = 0.01        # the table is rounded to 2 decimals; 0.005 rounding + margin
FOOTPRINTS = {"car": (4.25, 2.43), "warehouse_robot": (3.78, 3.61)}


def distance_to(shape, x: float, y: float) -> float:
    """Euclidean distance from (x, y) to a shape (0 inside), computed with shapely."""
    p = sg.Point(x, y)
    if isinstance(shape, Circle):
        return max(0.0, p.distance(sg.Point(*shape.center)) - shape.radius)
    return sg.Polygon(shape.vertices).distance(p)


# ---------------------------------------------------------------------------------------------
# Bench-MR SVG worlds

@pytest.mark.parametrize("world", sorted(BENCHMR_TABLE))
@pytest.mark.parametrize("hull", [False, True])
def test_benchmr_world_matches_source_table(world, hull):
    n, (x0, x1), (y0, y1) = BENCHMR_TABLE[world]
    m = load_benchmr_svg(MAZES / f"{world}.svg", convex_hull=hull)
    assert isinstance(m, Map) and m.name == world and m.source.endswith(f"{world}.svg")
    assert len(m.obstacles) == n and m.meta["polygons"] == n
    assert m.meta["scale"] == pytest.approx(1 / 22, rel=1e-12)
    xmin, ymin, xmax, ymax = m.bounds
    assert xmin == pytest.approx(x0, abs=RANGE_TOL) and xmax == pytest.approx(x1, abs=RANGE_TOL)
    assert ymin == pytest.approx(y0, abs=RANGE_TOL) and ymax == pytest.approx(y1, abs=RANGE_TOL)
    # bounds = bounding box of all polygons, exactly
    allv = np.concatenate([p.vertices for p in m.obstacles])
    assert m.bounds == (allv[:, 0].min(), allv[:, 1].min(), allv[:, 0].max(), allv[:, 1].max())
    for p in m.obstacles:
        poly = sg.Polygon(p.vertices)
        assert poly.is_valid, "every Bench-MR polygon is simple after dropping the closing vertex"
        assert poly.exterior.is_ccw
        if hull:   # convex: equal to its own hull (areas to 1e-9 relative)
            assert poly.convex_hull.area == pytest.approx(poly.area, rel=1e-9)


def test_benchmr_convex_hull_option_changes_only_nonconvex_shapes():
    true = load_benchmr_svg(MAZES / "parking3.svg")
    hull = load_benchmr_svg(MAZES / "parking3.svg", convex_hull=True)
    grown = [h.area - t.area for t, h in zip(true.obstacles, hull.obstacles)]
    assert min(grown) >= -1e-9
    assert sum(g > 0.5 for g in grown) >= 2          # parking3 has visibly non-convex kerbs (> 0.5 m^2)
    for t, h in zip(true.obstacles, hull.obstacles):   # hull area equals shapely's hull (1e-9 relative)
        assert h.area == pytest.approx(sg.Polygon(t.vertices).convex_hull.area, rel=1e-9)


@pytest.mark.parametrize("name", sorted(FOOTPRINTS))
def test_benchmr_footprint_size_and_centroid(name):
    fp = load_benchmr_footprint(MAZES / f"{name}.svg")
    assert isinstance(fp, Polygon)
    xmin, ymin, xmax, ymax = fp.bounds()
    length, width = FOOTPRINTS[name]
    assert xmax - xmin == pytest.approx(length, abs=0.01)
    assert ymax - ymin == pytest.approx(width, abs=0.01)
    c = sg.Polygon(fp.vertices).centroid                  # area centroid, by shapely
    assert abs(c.x) < 1e-9 and abs(c.y) < 1e-9


def test_benchmr_scenarios_csv():
    sc = load_benchmr_scenarios(MAZES / "polygon_scenarios.csv")
    assert sorted(sc) == sorted(BENCHMR_TABLE)
    assert all(len(v) == 5 for v in sc.values())
    first = sc["parking1"][0]
    assert (first.start.x, first.start.y, first.start.theta) == (0.0, -2.27, 0.0)
    assert (first.goal.x, first.goal.y, first.goal.theta) == (7.72, -7.72, -1.58)
    assert first.label == "parking1#0"


@pytest.mark.parametrize("hull", [False, True])
def test_benchmr_scenario_poses_are_in_free_space(hull):
    """Every published pose's reference point lies inside the bounds and outside every polygon."""
    sc = load_benchmr_scenarios(MAZES / "polygon_scenarios.csv")
    for world, problems in sc.items():
        m = load_benchmr_svg(MAZES / f"{world}.svg", convex_hull=hull)
        union = sg.MultiPolygon([sg.Polygon(p.vertices) for p in m.obstacles])
        for pr in problems:
            for pose in (pr.start, pr.goal):
                pt = sg.Point(pose.x, pose.y)
                assert m.contains(pose.x, pose.y), (pr.label, pose)
                assert not union.intersects(pt), (pr.label, pose)
                # and our own point-in-polygon test agrees with shapely
                assert not any(point_in_polygon(pose.x, pose.y, p.vertices) for p in m.obstacles)


SVG_HEAD = '<svg xmlns="http://www.w3.org/2000/svg" xmlns:svg="http://www.w3.org/2000/svg">'


def write_svg(tmp_path: Path, body: str, name: str = "tiny.svg") -> Path:
    p = tmp_path / name
    p.write_text(f'<?xml version="1.0"?>\n{SVG_HEAD}<g transform="translate(100,100)">{body}</g></svg>')
    return p


def test_svg_parser_relative_absolute_and_implicit_commands(tmp_path):
    body = (
        # L-shape: absolute M, relative h/v, relative l with an implicit second pair, absolute H, Z
        '<path d="M 0,0 h 44 v 22 l -22,0 0,22 H 0 Z"/>'
        # square: relative m followed by implicit relative lineto pairs, compact number syntax
        '<path transform="rotate(30)" d="m44,44 22,0 0,22-22,0z"/>'
        # absolute L with a repeated closing vertex (dropped), exponent and signed numbers
        '<path d="M 0 0 L 2.2e1 0 L 22 +22 L -.0e0 22 L 0 0"/>'
        # absolute V and H
        '<path d="M 0,66 H 22 V 88 H 0 V 66"/>'
    )
    m = load_benchmr_svg(write_svg(tmp_path, body))
    s = 1 / 22
    expected = [
        [(0, 0), (2, 0), (2, -1), (1, -1), (1, -2), (0, -2)],
        [(2, -2), (3, -2), (3, -3), (2, -3)],
        [(0, 0), (1, 0), (1, -1), (0, -1)],
        [(0, -3), (1, -3), (1, -4), (0, -4)],
    ]
    assert len(m.obstacles) == 4
    for poly, exp in zip(m.obstacles, expected):
        ref = sg.Polygon(exp)
        got = sg.Polygon(poly.vertices)
        assert len(poly.vertices) == len(exp)
        # same set of vertices (orientation is normalised to CCW), same region: to 1e-12
        assert got.symmetric_difference(ref).area < 1e-12
        assert sorted(map(tuple, np.round(poly.vertices, 12))) == sorted(map(tuple, np.round(np.array(exp, float), 12)))
    assert m.bounds == pytest.approx((0, -4, 3, 0), abs=1e-12)
    assert m.obstacles[0].area == pytest.approx(3.0, abs=1e-12)
    assert s == BENCHMR_SCALE


def test_parse_path_d_directly():
    v = parse_path_d("m 1,1 2,0 v 2 h -2 z")
    assert v.tolist() == [[1, 1], [3, 1], [3, 3], [1, 3]]


@pytest.mark.parametrize("d", [
    "M 0,0 C 1,1 2,2 3,0 z", "m 0,0 c 1,1 2,2 3,0 z", "M 0 0 S 1 1 2 0 Z", "m 0 0 q 1 1 2 0 z",
    "M 0 0 Q 1 1 2 0 Z", "m 0 0 a 5 5 0 0 1 10 0 z", "M 0 0 A 5 5 0 0 1 10 0 Z", "M 0 0 T 1 1 Z",
    "m 0 0 h 1 v 1 z m 5 5 h 1 v 1 z",          # two subpaths
    "M 0 0 h 1 v",                              # missing number
    "M 0 0 h 1 # 2",                            # garbage
    "10 10 h 1 v 1 z",                          # no moveto
])
def test_svg_unsupported_path_data_raises(tmp_path, d):
    p = write_svg(tmp_path, f'<path d="{d}"/>', name="bad_path.svg")
    with pytest.raises(MapError, match="bad_path.svg"):
        load_benchmr_svg(p)


@settings(max_examples=300, deadline=None)
@given(d=st.text(alphabet="MmLlHhVvZzCcAaQqSsTt0123456789.-+eE, \t\n", max_size=60))
def test_fuzz_path_data_only_map_errors(d):
    try:
        v = parse_path_d(d, "fuzz")
    except MapError as exc:
        assert "fuzz" in str(exc)
    else:
        assert v.ndim == 2 and v.shape[1] == 2 and len(v) >= 1 and np.isfinite(v).all()


@pytest.mark.parametrize("body,text", [
    ('<rect x="0" y="0" width="10" height="10"/>', "<rect>"),
    ('<path d="M 0 0 h 10 v 10 z"/><circle cx="0" cy="0" r="1"/>', "<circle>"),
    ("", "at least one <path>"),
    ('<path d="M 0 0 h 10 v 10 z"', "well-formed"),
])
def test_svg_bad_documents_raise(tmp_path, body, text):
    p = write_svg(tmp_path, body, name="bad_doc.svg")
    with pytest.raises(MapError, match="bad_doc.svg") as ei:
        load_benchmr_svg(p)
    assert text in str(ei.value)


# ---------------------------------------------------------------------------------------------
# our YAML maps

@pytest.mark.parametrize("name", OUR_MAPS)
def test_our_maps_load_with_clearance(name):
    m = load_yaml_map(OURS / f"{name}.yaml")
    assert m.obstacles and m.unknown_obstacles
    assert m.start is not None and m.goal is not None
    assert m.robot is not None and m.robot["model"] in ("rwd_car", "unicycle")
    assert m.source.endswith(f"{name}.yaml") and m.name
    for pose in (m.start, m.goal):
        assert m.contains(pose.x, pose.y)
        clearance = min(distance_to(s, pose.x, pose.y) for s in m.obstacles)
        assert clearance >= 1.0, (name, pose, clearance)
    for s in m.obstacles + m.unknown_obstacles:
        if isinstance(s, Polygon):
            assert sg.Polygon(s.vertices).is_valid
    # the header comment says what it depicts and that it is original to nhstab
    head = (OURS / f"{name}.yaml").read_text().splitlines()[:3]
    assert head[0].startswith("#") and "original to nhstab" in " ".join(head)


def test_our_maps_robots_and_nonconvex_pieces():
    models = {n: load_yaml_map(OURS / f"{n}.yaml").robot["model"] for n in OUR_MAPS}
    assert models == {"parking_lot": "rwd_car", "warehouse_corridor": "rwd_car", "cluttered_room": "unicycle"}
    room = load_yaml_map(OURS / "cluttered_room.yaml")
    nonconvex = [s for s in room.obstacles if isinstance(s, Polygon)
                 and sg.Polygon(s.vertices).convex_hull.area > s.area + 1e-6]
    assert len(nonconvex) >= 1
    assert any(isinstance(s, Circle) for s in room.obstacles)


# ---------------------------------------------------------------------------------------------
# YAML format: strict validation

VALID = """\
name: tiny
bounds: [0, 0, 10, 10]
obstacles:
  - polygon: [[1, 1], [3, 1], [3, 3], [1, 3]]
  - circle: {center: [7, 7], radius: 1.0}
  - box: {center: [7, 2], size: [2, 1], yaw: 0.5}
unknown_obstacles:
  - circle: {center: [5, 5], radius: 0.3}
start: [0.5, 5, 0]
goal: [9, 9, 1.57]
robot: {model: unicycle, footprint: {radius: 0.5}}
"""


def test_valid_tiny_yaml(tmp_path):
    p = tmp_path / "tiny.yaml"
    p.write_text(VALID)
    m = load_yaml_map(p)
    assert m.name == "tiny" and m.bounds == (0, 0, 10, 10)
    assert len(m.obstacles) == 3 and len(m.unknown_obstacles) == 1
    assert isinstance(m.obstacles[1], Circle) and m.obstacles[1].radius == 1.0
    box = sg.Polygon(m.obstacles[2].vertices)
    assert box.area == pytest.approx(2.0, abs=1e-12) and box.centroid.x == pytest.approx(7, abs=1e-12)
    assert m.robot == {"model": "unicycle", "footprint": {"radius": 0.5}}
    assert (m.start.x, m.start.y, m.start.theta) == (0.5, 5.0, 0.0)
    # no name -> file stem; a closing point equal to the first is dropped
    p2 = tmp_path / "other.yaml"
    p2.write_text("bounds: [0, 0, 1, 1]\nobstacles:\n  - polygon: [[0, 0], [1, 0], [0, 1], [0, 0]]\n")
    m2 = load_yaml_map(p2)
    assert m2.name == "other" and len(m2.obstacles[0].vertices) == 3 and m2.start is None


def _mutate(old: str, new: str) -> str:
    assert old in VALID
    return VALID.replace(old, new)


YAML_ERRORS = [
    ("unknown_top_key", VALID + "colour: red\n", "colour"),
    ("unknown_nested_key", _mutate("radius: 1.0}", "radius: 1.0, colour: red}"), "obstacles[1].circle.colour"),
    ("unknown_shape", _mutate("- circle: {center: [7, 7], radius: 1.0}", "- disc: {center: [7, 7], radius: 1.0}"),
     "obstacles[1].disc"),
    ("polygon_2_points", _mutate("[[1, 1], [3, 1], [3, 3], [1, 3]]", "[[1, 1], [3, 1]]"), "obstacles[0].polygon"),
    ("polygon_bowtie", _mutate("[[1, 1], [3, 1], [3, 3], [1, 3]]", "[[1, 1], [3, 3], [3, 1], [1, 3]]"),
     "obstacles[0].polygon"),
    ("nan", _mutate("bounds: [0, 0, 10, 10]", "bounds: [0, 0, .nan, 10]"), "bounds[2]"),
    ("inf", _mutate("center: [7, 7]", "center: [.inf, 7]"), "obstacles[1].circle.center[0]"),
    ("negative_radius", _mutate("radius: 1.0", "radius: -1.0"), "obstacles[1].circle.radius"),
    ("zero_box", _mutate("size: [2, 1]", "size: [2, 0]"), "obstacles[2].box.size"),
    ("bool_number", _mutate("yaw: 0.5", "yaw: true"), "obstacles[2].box.yaw"),
    ("string_number", _mutate("yaw: 0.5", "yaw: '0.5'"), "obstacles[2].box.yaw"),
    ("bounds_unordered", _mutate("bounds: [0, 0, 10, 10]", "bounds: [10, 0, 0, 10]"), "bounds"),
    ("bounds_missing", _mutate("bounds: [0, 0, 10, 10]\n", ""), "bounds"),
    ("start_outside", _mutate("start: [0.5, 5, 0]", "start: [-1, 5, 0]"), "start"),
    ("start_short", _mutate("start: [0.5, 5, 0]", "start: [0.5, 5]"), "start"),
    ("goal_in_polygon", _mutate("goal: [9, 9, 1.57]", "goal: [2, 2, 1.57]"), "goal"),
    ("goal_in_circle", _mutate("goal: [9, 9, 1.57]", "goal: [7.5, 7.5, 0]"), "goal"),
    ("goal_in_box", _mutate("goal: [9, 9, 1.57]", "goal: [7, 2, 0]"), "goal"),
    ("obstacles_not_list", _mutate("unknown_obstacles:\n  - circle: {center: [5, 5], radius: 0.3}",
                                   "unknown_obstacles: {circle: 1}"), "unknown_obstacles"),
    ("robot_no_model", _mutate("robot: {model: unicycle, footprint: {radius: 0.5}}", "robot: {footprint: {radius: 0.5}}"),
     "robot.model"),
    ("robot_nan", _mutate("robot: {model: unicycle, footprint: {radius: 0.5}}",
                          "robot: {model: unicycle, footprint: {radius: .nan}}"), "robot.footprint.radius"),
    ("robot_unknown_key", _mutate("robot: {model: unicycle, footprint: {radius: 0.5}}",
                                  "robot: {model: unicycle, radius: 0.5}"), "robot.radius"),
    ("missing_base", VALID + "base: {format: ros, path: nowhere/depot.yaml}\n", "base.path"),
    ("base_unknown_format", VALID + "base: {format: gif, path: x.gif}\n", "base.format"),
    ("base_bad_unknown", VALID + "base: {format: ros, path: x.yaml, unknown: maybe}\n", "base.unknown"),
    ("base_unknown_option", VALID + "base: {format: ros, path: x.yaml, cell_size: 1}\n", "base.cell_size"),
    ("bad_yaml", "bounds: [0, 0, 10\nobstacles: {\n", "bad_yaml.yaml"),
    ("tab_yaml", "bounds:\n\t- 1\n", "tab_yaml.yaml"),
    ("not_mapping", "- 1\n- 2\n", "not_mapping.yaml"),
    ("empty", "", "empty.yaml"),
]


@pytest.mark.parametrize("case,text,key", YAML_ERRORS, ids=[c[0] for c in YAML_ERRORS])
def test_yaml_errors_name_file_and_key(tmp_path, case, text, key):
    p = tmp_path / f"{case}.yaml"
    p.write_text(text)
    with pytest.raises(MapError) as ei:
        load_yaml_map(p)
    msg = str(ei.value)
    assert p.name in msg and key in msg, msg
    assert "\n" not in msg, "one-line errors"
    assert isinstance(ei.value, InputError) and isinstance(ei.value, ValueError)
    if case == "missing_base":
        assert "depot.yaml" in msg


def test_yaml_missing_file_and_not_utf8(tmp_path):
    with pytest.raises(MapError, match="absent.yaml"):
        load_yaml_map(tmp_path / "absent.yaml")
    p = tmp_path / "latin1.yaml"
    p.write_bytes(b"name: caf\xe9\nbounds: [0, 0, 1, 1]\n")
    with pytest.raises(MapError, match="latin1.yaml"):
        load_yaml_map(p)


def test_yaml_base_benchmr_svg_adds_obstacles_and_problems(tmp_path):
    sub = tmp_path / "worlds"
    sub.mkdir()
    text = (f"base: {{format: benchmr_svg, path: {MAZES / 'parking1.svg'}, convex_hull: true,\n"
            f"       scenarios: {MAZES / 'polygon_scenarios.csv'}}}\n"
            "obstacles:\n  - circle: {center: [5, 0], radius: 0.5}\n"
            "start: [0, -2.27, 0]\n")
    p = sub / "p1_plus.yaml"
    p.write_text(text)
    m = load_yaml_map(p)
    assert len(m.obstacles) == 14 and isinstance(m.obstacles[-1], Circle)
    assert m.bounds == load_benchmr_svg(MAZES / "parking1.svg").bounds
    assert len(m.problems) == 5 and m.problems[0].label == "parking1#0"
    assert m.meta["base"]["format"] == "benchmr_svg"
    # the YAML's bounds override; a start inside a parked car is refused
    car = load_benchmr_svg(MAZES / "parking1.svg").obstacles[3]
    cx, cy = sg.Polygon(car.vertices).representative_point().coords[0]
    p.write_text(text.replace("start: [0, -2.27, 0]", f"start: [{cx}, {cy}, 0]"))
    with pytest.raises(MapError, match=r"p1_plus\.yaml: start"):
        load_yaml_map(p)
    p.write_text(text + "bounds: [-5, -12, 25, 8]\n")
    assert load_yaml_map(p).bounds == (-5, -12, 25, 8)


def test_yaml_base_relative_path_and_wrapped_base_error(tmp_path):
    (tmp_path / "w").mkdir()
    (tmp_path / "w" / "curvy.svg").write_text(f'{SVG_HEAD}<path d="M 0 0 C 1 1 2 2 3 0 Z"/></svg>')
    p = tmp_path / "uses_curvy.yaml"
    p.write_text("base: {format: benchmr_svg, path: w/curvy.svg}\n")
    with pytest.raises(MapError) as ei:
        load_yaml_map(p)
    msg = str(ei.value)
    assert "uses_curvy.yaml: base.path" in msg and "curvy.svg" in msg and "\n" not in msg


needs_ros = pytest.mark.skipif(importlib.util.find_spec("nhstab.maps.ros") is None,
                               reason="pipeline/maps/ros.py not present")
needs_movingai = pytest.mark.skipif(importlib.util.find_spec("nhstab.maps.movingai") is None,
                                    reason="pipeline/maps/movingai.py not present")


@needs_ros
def test_yaml_base_ros_grid_checks_start_cells(tmp_path):
    depot = MAPS / "nav2" / "depot.yaml"
    grid = load_map(depot).grids[0]
    occ = grid.occupied
    # a free cell whose 5x5 neighbourhood is free, and an occupied cell (vectorised search)
    pad = np.pad(occ, 2, constant_values=True)
    window = np.lib.stride_tricks.sliding_window_view(pad, (5, 5)).any(axis=(-1, -2))
    fi, fj = np.argwhere(~window)[len(np.argwhere(~window)) // 2]
    oi, oj = np.argwhere(occ)[0]
    fx, fy = grid.cell_to_world(fi, fj)
    ox, oy = grid.cell_to_world(oi, oj)
    text = f"base: {{format: ros, path: {depot}, unknown: occupied}}\nobstacles:\n  - circle: {{center: [1, 1], radius: 0.2}}\n"
    p = tmp_path / "depot_plus.yaml"
    p.write_text(text + f"start: [{fx}, {fy}, 0]\n")
    m = load_yaml_map(p)
    assert len(m.grids) == 1 and m.bounds == grid.bounds() and len(m.obstacles) == 1
    p.write_text(text + f"start: [{ox}, {oy}, 0]\n")
    with pytest.raises(MapError, match=r"depot_plus\.yaml: start.*occupied cell"):
        load_yaml_map(p)


# ---------------------------------------------------------------------------------------------
# fuzzing: only PipelineErrors escape

_REAL_TEXTS = [(OURS / f"{n}.yaml").read_text() for n in OUR_MAPS] + [VALID]
_YAML_ALPHABET = st.sampled_from(list("abcxyz019.-+ ,:[]{}\n\t#&*!|>'\"?%@`") + ["polygon", "circle", "box",
                                 "center", "radius", "bounds", "start", "goal", "base", ".nan", ".inf", "1e999"])


@st.composite
def yaml_texts(draw) -> str:
    kind = draw(st.integers(0, 3))
    if kind == 0:
        return draw(st.text(max_size=200))
    if kind == 1:
        return "".join(draw(st.lists(_YAML_ALPHABET, max_size=60)))
    text = draw(st.sampled_from(_REAL_TEXTS))
    cut = draw(st.integers(0, len(text)))
    if kind == 2:
        return text[:cut]                                  # truncation of a real map
    junk = "".join(draw(st.lists(_YAML_ALPHABET, max_size=5)))
    return text[:cut] + junk + text[cut + draw(st.integers(0, 20)):]   # local corruption


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=yaml_texts())
def test_fuzz_yaml_only_pipeline_errors(tmp_path_factory, text):
    p = tmp_path_factory.mktemp("fuzz") / "fuzz.yaml"
    p.write_text(text, encoding="utf-8", errors="surrogatepass")   # lone surrogates -> invalid UTF-8
    try:
        m = load_yaml_map(p)
    except PipelineError as exc:
        assert "fuzz.yaml" in str(exc)
    else:
        assert isinstance(m, Map)


@settings(max_examples=200, deadline=None)
@given(pts=st.lists(st.tuples(st.integers(-5, 5), st.integers(-5, 5)), min_size=3, max_size=8))
def test_is_simple_polygon_agrees_with_shapely(pts):
    v = np.array(pts, dtype=float)
    if len(np.unique(v, axis=0)) < len(v):
        return                                            # repeated vertices: rejected by construction
    assert is_simple_polygon(v) == sg.LinearRing(v).is_simple


# ---------------------------------------------------------------------------------------------
# load_map dispatch

def test_load_map_svg_and_yaml():
    m = load_map(MAZES / "parking2.svg")
    assert len(m.obstacles) == 16 and len(m.problems) == 5 and m.meta["robot_shape"] == "car.svg"
    assert load_map(MAZES / "parking2.svg", scenarios=False).problems == ()
    assert load_map(str(MAZES / "warehouse.svg"), convex_hull=True).meta["convex_hull"] is True
    ours = load_map(OURS / "parking_lot.yaml")
    assert ours.name == "parking-lot" and ours.unknown_obstacles


def test_load_map_errors(tmp_path):
    with pytest.raises(MapError, match="nothing.svg"):
        load_map(tmp_path / "nothing.svg")
    (tmp_path / "drawing.png").write_bytes(b"\x89PNG")
    with pytest.raises(MapError, match="drawing.png"):
        load_map(tmp_path / "drawing.png")
    with pytest.raises(InputError, match="colour"):
        load_map(OURS / "parking_lot.yaml", colour="red")
    (tmp_path / "broken.yml").write_text("a: [\n")
    with pytest.raises(MapError, match="broken.yml"):
        load_map(tmp_path / "broken.yml")


@needs_ros
def test_load_map_ros_yaml():
    m = load_map(MAPS / "nav2" / "depot.yaml")
    assert len(m.grids) == 1 and m.obstacles == ()
    assert m.meta["format"] == "ros_map_server"
    free = load_map(MAPS / "nav2" / "depot.yaml", unknown="free")
    assert free.grids[0].occupied.sum() <= m.grids[0].occupied.sum()


@needs_movingai
def test_load_map_movingai():
    path = MAPS / "bench-mr" / "moving_ai_scenarios" / "Berlin_0_256.map"
    m = load_map(path, cell_size=0.5)
    assert len(m.grids) == 1 and m.grids[0].shape == (256, 256)
    assert m.size == pytest.approx((128.0, 128.0), abs=1e-9)
    assert len(m.problems) == 930                          # Berlin_0_256.map.scen, per SOURCE.md
    assert math.isclose(m.grids[0].resolution, 0.5)


@needs_movingai
def test_yaml_base_movingai_with_scenarios(tmp_path):
    room = MAPS / "movingai" / "64room_000.map"
    p = tmp_path / "room_plus.yaml"
    text = (f"base: {{format: movingai, path: {room}, cell_size: 0.25, scenarios: {room}.scen}}\n"
            "unknown_obstacles:\n  - box: {center: [10, 10], size: [1, 1]}\n")
    p.write_text(text)
    m = load_yaml_map(p)
    assert m.grids[0].shape == (512, 512) and m.bounds == pytest.approx((0, 0, 128, 128), abs=1e-9)
    assert len(m.problems) == 2030 and len(m.unknown_obstacles) == 1
    s = m.problems[0].start
    p.write_text(text + f"start: [{s.x}, {s.y}, 0]\n")       # a scenario start is a free cell
    assert load_yaml_map(p).start.x == s.x
    with pytest.raises(MapError, match=r"room_plus\.yaml: base\.cell_size"):
        p.write_text(text.replace("cell_size: 0.25", "cell_size: 0"))
        load_yaml_map(p)
