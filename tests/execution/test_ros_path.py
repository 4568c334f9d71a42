"""Plans and runs as ROS 2 nav_msgs/Path messages (nhstab.ros_path, nhstab export ros2-path).

The message is checked field by field against its definition (nav_msgs/Path, std_msgs/Header,
builtin_interfaces/Time, geometry_msgs/PoseStamped, Pose, Point, Quaternion), the YAML is read back
with PyYAML (the reader ros2 topic pub uses), and the coordinates of a plan on a map_server map with a
non-zero origin are checked against the map's own image: every exported pose, placed by map_server's
rule (pixel = floor((x - origin) / resolution), image row 0 at the top), is in a free pixel and the
footprint's radius away from every occupied one.
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from nhstab.errors import InputError
from nhstab.models import make_model
from nhstab.nav2 import read_nav2_robot
from nhstab.ros_path import (
    export_path,
    path_message,
    quaternion_yaw,
    read_folder,
    ros_stamp,
    segments,
    to_yaml,
    travel_directions,
    yaw_quaternion,
)
from PIL import Image

from tests.clitools import invoke, one_line

ORIGIN = (-3.2, 7.5)
RES = 0.05
START, GOAL = (-2.6, 8.3, 0.0), (0.2, 8.3, 0.0)
RADIUS = 0.3                     # the unicycle's built-in disc


def _room(folder):
    """A map_server map: 80 x 60 pixels at 0.05 m with origin (-3.2, 7.5), walls round it and a wall
    from the bottom up to 1.5 m between the start and the goal."""
    img = np.full((60, 80), 254, np.uint8)
    img[:2, :] = 0
    img[-2:, :] = 0
    img[:, :2] = 0
    img[:, -2:] = 0
    img[60 - 30:, 36:44] = 0
    Image.fromarray(img).save(folder / "room.pgm")
    (folder / "room.yaml").write_text(f"image: room.pgm\nresolution: {RES}\norigin: [{ORIGIN[0]}, {ORIGIN[1]}, 0.0]\n"
                                      "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return folder / "room.yaml"


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    return _room(tmp_path_factory.mktemp("room"))


@pytest.fixture(scope="module")
def plan_dir(room):
    out = room.parent / "plan"
    res = invoke("plan", room, "--robot", "unicycle", "--start", ",".join(map(str, START)),
                 "--goal", ",".join(map(str, GOAL)), "--out", out, "--no-figure", "--tube", "linear")
    assert res.exit_code in (0, 1), res.output          # 1: written, tube not predicted
    return out


# ---- the message against its definition ----------------------------------------------------------
def _check_time(stamp):
    assert set(stamp) == {"sec", "nanosec"}
    assert type(stamp["sec"]) is int and -2**31 <= stamp["sec"] < 2**31             # int32
    assert type(stamp["nanosec"]) is int and 0 <= stamp["nanosec"] < 10**9           # uint32, < 1 s


def _check_header(h):
    assert set(h) == {"stamp", "frame_id"} and isinstance(h["frame_id"], str)
    _check_time(h["stamp"])


def _check_path(msg):
    assert set(msg) == {"header", "poses"}
    _check_header(msg["header"])
    for p in msg["poses"]:
        assert set(p) == {"header", "pose"}
        _check_header(p["header"])
        assert set(p["pose"]) == {"position", "orientation"}
        assert set(p["pose"]["position"]) == {"x", "y", "z"}
        assert set(p["pose"]["orientation"]) == {"x", "y", "z", "w"}
        for v in (*p["pose"]["position"].values(), *p["pose"]["orientation"].values()):
            assert type(v) is float and math.isfinite(v)                                 # float64


def test_the_quaternion_of_a_yaw_gives_the_yaw_back():
    rng = np.random.default_rng(7)
    yaws = np.concatenate([rng.uniform(-math.pi, math.pi, 2000), [0.0, math.pi / 2, -math.pi / 2, 1e-300,
                                                                   math.nextafter(math.pi, 0.0), -math.pi]])
    for yaw in yaws:
        q = yaw_quaternion(float(yaw))
        assert q[0] == 0.0 and q[1] == 0.0 and abs(math.hypot(*q) - 1.0) <= 1e-15
        back = quaternion_yaw(q)
        assert abs(math.remainder(back - yaw, 2 * math.pi)) <= 1e-12
    # angles beyond pi (a heading that wound round) come back wrapped
    for yaw in (3 * math.pi / 2, -7.0, 12.5):
        assert abs(math.remainder(quaternion_yaw(yaw_quaternion(yaw)) - yaw, 2 * math.pi)) <= 1e-12


def test_stamps_are_rounded_to_the_nanosecond():
    assert ros_stamp(0.0) == {"sec": 0, "nanosec": 0}
    assert ros_stamp(1.5) == {"sec": 1, "nanosec": 500_000_000}
    assert ros_stamp(0.02) == {"sec": 0, "nanosec": 20_000_000}
    assert ros_stamp(1699999999.999999999) == {"sec": 1700000000, "nanosec": 0}
    assert ros_stamp(2.9999999994) == {"sec": 2, "nanosec": 999_999_999}


def test_a_path_message_has_the_definitions_fields_and_monotone_stamps():
    t = np.linspace(0.0, 3.0, 151)
    poses = np.column_stack([np.cos(t), np.sin(t), t + math.pi / 2])
    msg = path_message(t, poses, frame_id="odom", stamp=100.25)
    _check_path(msg)
    assert len(msg["poses"]) == 151 and msg["header"]["frame_id"] == "odom"
    ns = [p["header"]["stamp"]["sec"] * 10**9 + p["header"]["stamp"]["nanosec"] for p in msg["poses"]]
    assert ns == [round((100.25 + ti) * 1e9) for ti in t]
    assert all(b > a for a, b in zip(ns, ns[1:]))
    assert msg["header"]["stamp"] == ros_stamp(100.25)
    for p, (x, y, th) in zip(msg["poses"], poses):
        assert p["pose"]["position"] == {"x": x, "y": y, "z": 0.0}
        assert abs(math.remainder(quaternion_yaw(p["pose"]["orientation"].values()) - th, 2 * math.pi)) <= 1e-12


def test_the_yaml_reads_back_as_the_same_message_with_pyyaml():
    # tiny and huge values whose shortest text (1e-05, 1e+16) YAML 1.1 would read as strings
    t = np.array([0.0, 1e-5, 0.5, 2.0])
    poses = np.array([[1e-5, -2.5e-7, 1e-9], [1e16, 3.0, -1e-300], [0.1, 0.2, 3.1], [-0.0, 5.0, -3.14159]])
    msg = path_message(t, poses, stamp=7.0)
    back = yaml.safe_load(to_yaml(msg))
    _check_path(back)
    assert back == msg


@pytest.mark.parametrize("frame", ["", "map frame", "map\n", "a" * 257, 3])
def test_a_bad_frame_id_is_refused(frame):
    with pytest.raises(InputError, match="--frame"):
        path_message([0.0], [[0.0, 0.0, 0.0]], frame_id=frame)


@pytest.mark.parametrize("stamp", [-1.0, math.nan, math.inf, 2.0**31])
def test_a_bad_stamp_is_refused(stamp):
    with pytest.raises(InputError, match="stamp"):
        path_message([0.0, 1.0], [[0.0, 0.0, 0.0]] * 2, stamp=stamp)


# ---- directions -------------------------------------------------------------------------------
def test_directions_and_segments_of_a_forward_stop_reverse_nominal():
    model = make_model("unicycle")
    v = np.array([0.0, 0.5, 0.5, 0.5, 0.0, 0.0, -0.4, -0.4, 0.0, 0.0])
    u = np.column_stack([v, np.zeros_like(v)])
    x = np.zeros((len(v), 3))
    x[:, 2] = 0.7                                             # the heading does not change the sign
    d = travel_directions(model, x, u)
    # the stop before the first move and at the cusp take the next move's direction, the end the last one's
    assert d.tolist() == [1, 1, 1, 1, -1, -1, -1, -1, -1, -1]
    assert segments(d) == [(0, 3, 1), (4, 9, -1)]
    car = make_model("rwd_car")
    xc = np.zeros((4, 4))
    xc[:, 2] = math.pi                                        # facing -x, driving backwards along +x
    uc = np.array([[-1.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [1.0, 0.0]])
    assert travel_directions(car, xc, uc).tolist() == [-1, -1, 1, 1]


# ---- a plan on a map_server map ----------------------------------------------------------------
def _free_and_clear(room, poses, radius=RADIUS):
    """Each pose in a free pixel by map_server's rule, and ``radius`` from every occupied pixel's square."""
    img = np.asarray(Image.open(room.parent / "room.pgm"), dtype=float)
    p = (255.0 - img) / 255.0
    occupied_rows, occupied_cols = np.nonzero(p > 0.65)
    h = img.shape[0]
    # the squares of occupied pixels in world coordinates (image row 0 is the top)
    x0 = ORIGIN[0] + occupied_cols * RES
    y0 = ORIGIN[1] + (h - 1 - occupied_rows) * RES
    for x, y in poses:
        col, row_up = math.floor((x - ORIGIN[0]) / RES), math.floor((y - ORIGIN[1]) / RES)
        assert 0 <= col < img.shape[1] and 0 <= row_up < h
        assert p[h - 1 - row_up, col] < 0.196                 # free
        dx = np.maximum(np.maximum(x0 - x, x - (x0 + RES)), 0.0)
        dy = np.maximum(np.maximum(y0 - y, y - (y0 + RES)), 0.0)
        assert np.hypot(dx, dy).min() >= radius - 1e-9


def test_a_plan_on_a_ros_map_is_exported_in_the_map_frame(room, plan_dir, tmp_path):
    got = export_path(plan_dir, tmp_path / "path.yaml")
    msg = yaml.safe_load((tmp_path / "path.yaml").read_text())
    _check_path(msg)
    assert msg == got["message"]
    data = read_folder(plan_dir)
    assert data["kind"] == "plan" and len(msg["poses"]) == len(data["t"]) == got["poses"]
    xy = np.array([[p["pose"]["position"]["x"], p["pose"]["position"]["y"]] for p in msg["poses"]])
    yaw = np.array([quaternion_yaw(p["pose"]["orientation"].values()) for p in msg["poses"]])
    # the nominal's own samples, unchanged; it starts at the start as given, in ROS map coordinates, and ends
    # within its recorded deviation from the geometric path of the goal
    with np.load(plan_dir / "trajectory.npz") as npz:
        assert np.array_equal(xy, npz["x"][:, :2]) and np.array_equal(data["t"], npz["t"])
    assert np.allclose(xy[0], START[:2], atol=1e-9)
    deviation = json.loads((plan_dir / "plan.json").read_text())["metrics"]["path_deviation_m"]
    assert math.dist(xy[-1], GOAL[:2]) <= deviation + 1e-9
    assert abs(math.remainder(yaw[0] - START[2], 2 * math.pi)) <= 1e-9
    _free_and_clear(room, xy)
    # the path goes round the wall: above its top at 9.0 m where it crosses it
    crossing = (xy[:, 0] > ORIGIN[0] + 36 * RES) & (xy[:, 0] < ORIGIN[0] + 44 * RES)
    assert crossing.any() and xy[crossing, 1].min() >= ORIGIN[1] + 30 * RES + RADIUS - 1e-9
    stamps = [p["header"]["stamp"]["sec"] + 1e-9 * p["header"]["stamp"]["nanosec"] for p in msg["poses"]]
    assert all(b >= a for a, b in zip(stamps, stamps[1:]))
    assert stamps[-1] == pytest.approx(data["t"][-1], abs=1e-9)
    # the YAML's comments list the cusps and every segment
    text = (tmp_path / "path.yaml").read_text()
    assert f"# cusps (pose indices where the direction changes): {got['cusps']}" in text
    assert text.count("# segment poses") == len(got["segments"]) == len(got["cusps"]) + 1


def test_stride_keeps_the_ends_and_every_segments_ends(plan_dir, tmp_path):
    full = export_path(plan_dir, tmp_path / "full.yaml")
    thin = export_path(plan_dir, tmp_path / "thin.yaml", stride=10)
    n = full["poses"]
    assert thin["poses"] < n / 5 + 2 * len(full["segments"]) + 2
    times = [p["header"]["stamp"] for p in thin["message"]["poses"]]
    assert times[0] == full["message"]["poses"][0]["header"]["stamp"]
    assert times[-1] == full["message"]["poses"][-1]["header"]["stamp"]
    assert len(thin["segments"]) == len(full["segments"])
    assert [d for _, _, d in thin["segments"]] == [d for _, _, d in full["segments"]]


def test_the_json_form_and_its_segments_file(plan_dir, tmp_path):
    got = export_path(plan_dir, tmp_path / "path.json", fmt="json", frame_id="world", stamp=12.5)
    msg = json.loads((tmp_path / "path.json").read_text())
    _check_path(msg)
    assert msg == got["message"] and msg["header"]["frame_id"] == "world"
    side = json.loads((tmp_path / "path.segments.json").read_text())
    assert side["cusps"] == got["cusps"]
    assert [(s["first"], s["last"], s["direction"]) for s in side["segments"]] == got["segments"]


def test_export_refuses_what_is_not_a_plan_or_run_folder(plan_dir, tmp_path):
    with pytest.raises(InputError, match="FOLDER"):
        export_path(tmp_path, tmp_path / "x.yaml")
    with pytest.raises(InputError, match="--out"):
        export_path(plan_dir, plan_dir / "plan.json", fmt="json")
    with pytest.raises(InputError, match="--stride"):
        export_path(plan_dir, tmp_path / "x.yaml", stride=0)
    (tmp_path / "plan.json").write_text("[1, 2]")
    with pytest.raises(InputError, match="inputs.robot"):
        export_path(tmp_path, tmp_path / "x.yaml")


# ---- the command line ------------------------------------------------------------------------
def test_the_command_writes_the_yaml_and_says_what_it_holds(plan_dir, tmp_path):
    res = invoke("export", "ros2-path", plan_dir, "-o", tmp_path / "p.yaml", "--frame", "map", "--stride", "3")
    assert res.exit_code == 0, res.output
    assert "nav_msgs/Path of the plan" in res.output and "frame 'map'" in res.output
    _check_path(yaml.safe_load((tmp_path / "p.yaml").read_text()))
    one_line(invoke("export", "ros2-path", plan_dir, "-o", tmp_path / "q.yaml", "--frame", "my frame"), 2, "--frame")
    one_line(invoke("export", "ros2-path", tmp_path, "-o", tmp_path / "q.yaml"), 2, "FOLDER")


def test_a_run_folder_exports_the_simulated_trajectory(room, tmp_path):
    out = tmp_path / "run"
    res = invoke("run", room, "--robot", "unicycle", "--start", ",".join(map(str, START)),
                 "--goal", ",".join(map(str, GOAL)), "--out", out, "--seed", "3")
    assert (out / "run.json").is_file(), res.output
    res = invoke("export", "ros2-path", out, "-o", tmp_path / "run.yaml")
    assert res.exit_code == 0, res.output
    msg = yaml.safe_load((tmp_path / "run.yaml").read_text())
    _check_path(msg)
    data = read_folder(out)
    assert data["kind"] == "run" and len(msg["poses"]) == len(data["t"])
    xy = np.array([[p["pose"]["position"]["x"], p["pose"]["position"]["y"]] for p in msg["poses"]])
    assert np.array_equal(xy, data["poses"][:, :2])
    _free_and_clear(room, xy[::10])


def test_a_nav2_robot_plans_on_a_ros_map_and_its_plan_goes_back_as_a_path(room, tmp_path):
    """The round trip a Nav2 user makes: the robot of nav2_params.yaml (--robot-config), a plan on a
    map_server map, the plan back as a nav_msgs/Path in the map frame."""
    params = Path(__file__).resolve().parents[1] / "data" / "nav2" / "nav2_params.yaml"
    out = tmp_path / "plan"
    res = invoke("plan", room, "--robot-config", f"nav2:{params}", "--start", ",".join(map(str, START)),
                 "--goal", ",".join(map(str, GOAL)), "--out", out, "--no-figure", "--tube", "linear")
    assert (out / "plan.json").is_file(), res.output
    assert "nav2: footprint disc r = 0.22 m + footprint_padding 0.01 m" in res.stderr
    assert "nav2: model unicycle" in res.stderr
    used = json.loads((out / "plan.json").read_text())["inputs"]["robot"]
    want = read_nav2_robot(params).robot
    assert used["footprint"] == {"radius": 0.23} and used["max_speed"] == 0.26 and used["max_turn_rate"] == 1.0
    assert {k: used[k] for k in want.spec()} == want.spec() and used["source"] == f"nav2:{params}"
    got = export_path(out, tmp_path / "path.yaml")
    xy = np.array([[p["pose"]["position"]["x"], p["pose"]["position"]["y"]] for p in got["message"]["poses"]])
    _free_and_clear(room, xy, radius=0.23)


# ---- against ROS 2's own message definitions (rosbags' type stores, no ROS installation) ------------
_INTS = {"int32": (-2**31, 2**31 - 1), "uint32": (0, 2**32 - 1)}


def _build(ts, typename, value):
    """The rosbags message of ``typename`` from the exported dict: every field of the definition present,
    no other, each base value of its exact type and range."""
    from rosbags.interfaces import Nodetype

    fields = ts.get_msgdef(typename).fields
    assert isinstance(value, dict) and set(value) == {name for name, _ in fields}, (typename, value)
    kwargs = {}
    for name, (node, detail) in fields:
        v = value[name]
        if node == Nodetype.NAME:
            kwargs[name] = _build(ts, detail, v)
        elif node == Nodetype.SEQUENCE:
            (sub, subtype), _bound = detail
            assert sub == Nodetype.NAME and isinstance(v, list)
            kwargs[name] = [_build(ts, subtype, a) for a in v]
        else:
            base = detail[0]
            if base in _INTS:
                lo, hi = _INTS[base]
                assert type(v) is int and lo <= v <= hi, (typename, name, v)
            elif base == "float64":
                assert type(v) is float, (typename, name, v)
            else:
                assert base == "string" and isinstance(v, str), (typename, name, v)
            kwargs[name] = v
    return ts.types[typename](**kwargs)


def _as_dict(msg, ts, typename):
    from rosbags.interfaces import Nodetype

    out = {}
    for name, (node, detail) in ts.get_msgdef(typename).fields:
        v = getattr(msg, name)
        if node == Nodetype.NAME:
            out[name] = _as_dict(v, ts, detail)
        elif node == Nodetype.SEQUENCE:
            out[name] = [_as_dict(a, ts, detail[0][1]) for a in v]
        else:
            out[name] = v
    return out


@pytest.mark.parametrize("store", ["ROS2_HUMBLE", "ROS2_JAZZY"])
def test_the_exported_path_is_a_nav_msgs_path_of_ros2(plan_dir, tmp_path, store):
    """The YAML, read as ros2 topic pub reads it, fills nav_msgs/msg/Path field by field by the
    distribution's own definitions, serializes to CDR and comes back unchanged."""
    typesys = pytest.importorskip("rosbags.typesys")
    ts = typesys.get_typestore(getattr(typesys.Stores, store))
    export_path(plan_dir, tmp_path / "path.yaml", stamp=1.7e9)
    value = yaml.safe_load((tmp_path / "path.yaml").read_text())
    msg = _build(ts, "nav_msgs/msg/Path", value)
    raw = ts.serialize_cdr(msg, "nav_msgs/msg/Path")
    back = ts.deserialize_cdr(raw, "nav_msgs/msg/Path")
    assert _as_dict(back, ts, "nav_msgs/msg/Path") == value
    assert len(back.poses) == len(read_folder(plan_dir)["t"])
