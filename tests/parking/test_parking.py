"""The parking suite: the closed forms against brute force, the generated maps
against their stated geometry, and the commands that make and measure them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from nhstab import parking as P
from nhstab.cli.main import cli
from nhstab.collision import CollisionWorld
from nhstab.examples import list_examples, resolve_map_path
from nhstab.maps import load_map
from nhstab.robot import robot_from_spec

shapely = pytest.importorskip("shapely")
from shapely.geometry import Polygon as SPolygon  # noqa: E402
from shapely.geometry import box as sbox

ROOT = Path(__file__).resolve().parents[2]
FOLDER = ROOT / "maps" / "parking"


@pytest.fixture(scope="module")
def cases():
    return P.suite()


@pytest.fixture(scope="module")
def rows():
    return {r["name"]: r for r in P.read_suite_csv(FOLDER / "suite.csv")}


def _car(spec: dict):
    """(L, w, b, f, R) of a robot description, read directly (not through CarGeometry)."""
    rect = spec["footprint"]["rectangle"]
    L, w, b = spec["wheelbase"], rect["width"], rect["rear_overhang"]
    return L, w, b, rect["length"] - b - L, L / math.tan(spec["max_steer"])


def _body(L, w, b, f, pose, grow=0.0) -> SPolygon:
    x, y, th = pose
    local = np.array([[-b - grow, -w / 2 - grow], [L + f + grow, -w / 2 - grow], [L + f + grow, w / 2 + grow],
                      [-b - grow, w / 2 + grow]])
    c, s = math.cos(th), math.sin(th)
    return SPolygon(local @ np.array([[c, s], [-s, c]]) + [x, y])


# ---- the closed forms -------------------------------------------------------------------------------

def test_l1_of_the_default_rwd_car_is_5_80_m_for_its_4_2_m_body():
    car = P.CarGeometry.from_robot(robot_from_spec("rwd_car"))
    assert car.length == pytest.approx(4.2) and car.front_overhang == pytest.approx(0.8)
    # L 2.5, w 1.8, b 0.9, f 0.8, R = 2.5 / tan(0.6)
    R = 2.5 / math.tan(0.6)
    by_hand = 0.9 + math.sqrt((R + 0.9) ** 2 + 3.3 ** 2 - (R - 0.9) ** 2)
    assert P.parallel_min_length(car) == pytest.approx(by_hand, abs=1e-12)
    assert round(P.parallel_min_length(car), 2) == 5.80


def _l1_brute_force(L, w, b, f, R, n=2000) -> tuple[float, float]:
    """Sweep the car backwards out of its slot (a left arc about (0, R) from the parked pose at the
    origin, 0 .. 90 degrees) with shapely: the car ahead (in line, its lane-side edge at w/2) must
    start beyond the swept body's farthest x below y = w/2; the car behind at -b. The sweep is
    sampled at n angles, then twice more densely around the farthest sample. Returns that minimum
    slot and how far the sweep reaches behind -b (must be <= 0)."""
    lane_side = sbox(-50.0, -w / 2 - 5.0, 50.0, w / 2)

    def reach(phi):
        body = _body(L, w, b, f, (R * math.sin(phi), R - R * math.cos(phi), phi)).intersection(lane_side)
        return (-math.inf, -math.inf) if body.is_empty else (body.bounds[2], -b - body.bounds[0])

    lo, hi = 0.0, math.pi / 2
    behind = -math.inf
    for _ in range(3):
        phis = np.linspace(lo, hi, n)
        values = [reach(p) for p in phis]
        behind = max(behind, max(v[1] for v in values))
        k = int(np.argmax([v[0] for v in values]))
        front = values[k][0]
        step = (hi - lo) / (n - 1)
        lo, hi = max(0.0, phis[k] - 2 * step), min(math.pi / 2, phis[k] + 2 * step)
    return b + front, behind


@pytest.mark.parametrize("car", ["rwd_car", "van", "random0", "random1", "random2"])
def test_l1_formula_equals_a_brute_force_sweep_of_the_maneuver(car):
    if car.startswith("random"):
        rng = np.random.default_rng(100 + int(car[-1]))
        L = rng.uniform(2.0, 4.0)
        spec = {"wheelbase": L, "max_steer": rng.uniform(0.45, 0.75), "footprint": {"rectangle": {
            "length": L + rng.uniform(1.2, 2.6), "width": rng.uniform(1.5, 2.2), "rear_overhang": rng.uniform(0.5, 1.2)}}}
    else:
        spec = P.cars()[car]
    L, w, b, f, R = _car(spec)
    geo = P.CarGeometry(wheelbase=L, width=w, length=L + f + b, rear_overhang=b, min_turning_radius=R)
    brute, behind = _l1_brute_force(L, w, b, f, R)
    # a sampled sweep can only fall short of the true one (by < 1e-6 m after the refinement)
    assert P.parallel_min_length(geo) == pytest.approx(brute, abs=1e-5)
    assert P.parallel_min_length(geo) >= brute - 1e-9
    assert behind <= 1e-9       # the rear swings towards the lane, never into the car behind


def _a90_brute_force(L, w, b, f, R, bay_width, n=6000) -> float:
    """Reverse-in perpendicular parking backwards in time, with shapely: straight out of the bay up
    to rear-axle height yc, then a right arc about (R, yc) to heading 0. The neighbours (the car's
    size, centred in the next bays, ends flush with the aisle line y = 0) must not be touched; the
    smallest feasible yc (bisection) gives the aisle: the highest point of the swept body."""
    c = bay_width - w / 2
    neighbours = [sbox(c, -(L + f + b), c + w, 0.0), sbox(-c - w, -(L + f + b), -c, 0.0)]

    phis = np.linspace(0.0, math.pi / 2, n)
    local = np.array([[-b, -w / 2], [L + f, -w / 2], [L + f, w / 2], [-b, w / 2]])

    def sweep(yc):
        th = math.pi / 2 - phis
        c, s = np.cos(th), np.sin(th)
        x = (R - R * np.cos(phis))[:, None] + c[:, None] * local[:, 0] - s[:, None] * local[:, 1]
        y = (yc + R * np.sin(phis))[:, None] + s[:, None] * local[:, 0] + c[:, None] * local[:, 1]
        bodies = shapely.polygons(np.stack([x, y], axis=-1))
        hit = any(shapely.intersects(bodies, nb).any() for nb in neighbours)
        return hit, float(y.max())

    lo, hi = -(L + f + b), 0.0
    assert sweep(lo)[0] and not sweep(hi)[0]
    while hi - lo > 1e-6:
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if sweep(mid)[0] else (lo, mid)
    return sweep(hi)[1]


@pytest.mark.parametrize("car", ["rwd_car", "van"])
def test_a90_formula_equals_a_brute_force_sweep_and_the_numeric_estimate(car, cases):
    spec = P.cars()[car]
    L, w, b, f, R = _car(spec)
    W = w + P.BAY_EXTRA_WIDTH
    geo = P.CarGeometry.from_robot(robot_from_spec(spec))
    closed = P.perpendicular_min_aisle(geo, W)
    assert closed == pytest.approx(_a90_brute_force(L, w, b, f, R, W), abs=1e-4)
    # the library's numeric estimate (exact rectangle tests) on the suite's own row agrees too
    case = next(c for c in cases if c.car == car and c.kind == "perpendicular")
    row = [bx for bx in case.obstacles if not bx.label.startswith(("parked opposite", "far", "row end"))
           or bx.cy < 0]
    assert P.swept_aisle_width(row, geo, case.goal, reverse_in=True)["aisle_m"] == pytest.approx(closed, abs=1e-4)
    assert case.reference_m == pytest.approx(closed, abs=1e-12)


def test_the_tail_dip_is_what_the_arc_sweeps():
    geo = P.CarGeometry.from_robot(robot_from_spec("rwd_car"))
    R = geo.min_turning_radius
    # the curb-side rear corner's lowest point on the straightening arc, sampled
    lowest = min(_body(2.5, 1.8, 0.9, 0.8, (R * math.sin(p), R - R * math.cos(p), p)).bounds[1]
                 for p in np.linspace(0.0, 0.5, 20001))
    assert -0.9 - lowest == pytest.approx(P._tail_dip(geo, R), abs=1e-6)


def test_bad_cars_and_bays_are_refused():
    from nhstab.errors import InputError

    with pytest.raises(InputError, match="footprint"):
        P.CarGeometry.from_robot(robot_from_spec({"model": "rwd_car", "footprint": {"radius": 1.0}}))
    with pytest.raises(InputError, match="robot"):
        P.CarGeometry.from_robot(robot_from_spec("unicycle"))
    geo = P.CarGeometry.from_robot(robot_from_spec("rwd_car"))
    with pytest.raises(InputError, match="bay_width"):
        P.perpendicular_min_aisle(geo, 1.0)


# ---- the committed suite ------------------------------------------------------------------------------

def test_committed_folder_is_what_the_command_writes(tmp_path):
    assert P.write_suite(FOLDER, check=True) == {"differ": [], "missing": [], "extra": []}
    res = CliRunner().invoke(cli, ["parking", "suite", "--out", str(tmp_path / "p")])
    assert res.exit_code == 0, res.output
    written = sorted(p.name for p in (tmp_path / "p").iterdir())
    assert written == sorted(p.name for p in FOLDER.iterdir() if p.is_file())
    for name in written:
        assert (tmp_path / "p" / name).read_bytes() == (FOLDER / name).read_bytes(), name
    res = CliRunner().invoke(cli, ["parking", "suite", "--check", "--out", str(tmp_path / "p")])
    assert res.exit_code == 0 and "up to date" in res.output
    (tmp_path / "p" / "parallel_van_100.yaml").write_text("name: x\n")
    (tmp_path / "p" / "SOURCE.md").unlink()
    res = CliRunner().invoke(cli, ["parking", "suite", "--check", "--out", str(tmp_path / "p")])
    assert res.exit_code == 1
    assert "differ: parallel_van_100.yaml" in res.output and "missing: SOURCE.md" in res.output


def test_the_suite_covers_the_issue(rows):
    kinds = {}
    for r in rows.values():
        kinds.setdefault((r["car"], r["kind"]), []).append(r["factor"])
    assert {car for car, _ in kinds} == {"rwd_car", "van"}
    for car in ("rwd_car", "van"):
        assert sorted(kinds[(car, "parallel")]) == [0.9, 1.0, 1.05, 1.1, 1.2, 1.4]
        assert len(kinds[(car, "perpendicular")]) >= 3          # generous down to tight
        assert kinds[(car, "angled45")] and kinds[(car, "angled60")]


def test_names_are_unique_bundled_examples(rows):
    examples = {e.name: e for e in list_examples()}
    names = [e.name for e in list_examples()]
    assert len(names) == len(set(names))
    for name in rows:
        assert name in examples, name
        path = resolve_map_path(f"example:{name}")
        assert path.name == f"{name}.yaml" and path.parent.name == "parking"
        assert load_map(f"example:{name}").name == name
        assert examples[name].description.startswith(rows[name]["description"][:40])


def _polys(m):
    return [SPolygon(s.vertices) for s in m.obstacles]


@pytest.mark.parametrize("name", [c.name for c in P.suite()])
def test_case_geometry(name, rows):
    """Read back from the map file alone: the slot or aisle is its stated multiple of L1 or of the
    estimate to 1e-9 m; start and goal are clear of every obstacle by the car's margin (FCL and
    shapely); the goal lies inside its slot or bay; the map's robot is the stated car."""
    row = rows[name]
    m = load_map(FOLDER / f"{name}.yaml")
    spec = dict(m.robot)
    assert spec == P.cars()[row["car"]]
    robot = robot_from_spec(spec)
    L, w, b, f, R = _car(spec)
    margin = robot.margin
    assert margin == pytest.approx(0.1)
    start, goal = m.start.as_array(), m.goal.as_array()
    assert tuple(start) == (row["start_x"], row["start_y"], row["start_theta"])
    polys = _polys(m)
    world = CollisionWorld.from_map(m)
    for pose in (start, goal):
        assert world.is_free(pose, robot.footprint, margin)
        body = _body(L, w, b, f, pose)
        assert min(body.distance(p) for p in polys) > margin
        xmin, ymin, xmax, ymax = m.bounds
        bx = body.bounds
        assert min(bx[0] - xmin, bx[1] - ymin, xmax - bx[2], ymax - bx[3]) > margin
    goal_body = _body(L, w, b, f, goal)
    if row["kind"] == "parallel":
        # the slot: between the nearest cars behind and ahead of the goal, from the curb (y = 0) to
        # the parked cars' lane-side edge
        cars_ = [p for p in polys if abs(p.area - (L + f + b) * w) < 1e-6]
        behind = max(p.bounds[2] for p in cars_ if p.bounds[2] <= goal[0])
        ahead = min(p.bounds[0] for p in cars_ if p.bounds[0] >= goal[0])
        curb = max(p.bounds[3] for p in polys if p.bounds[3] <= 1e-9)
        l1 = b + math.sqrt((R + w / 2) ** 2 + (L + f) ** 2 - (R - w / 2) ** 2)
        assert ahead - behind == pytest.approx(row["factor"] * l1, abs=1e-9, rel=0)
        assert row["reference_m"] == pytest.approx(l1, abs=1e-9)
        lane_side = max(p.bounds[3] for p in cars_)
        slot = sbox(behind, curb, ahead, lane_side)
        assert slot.covers(goal_body)
        assert abs(goal[2]) < 1e-12
        # the start is in the lane, beyond the parked cars
        assert _body(L, w, b, f, start).bounds[1] > lane_side
    else:
        # the aisle: between the row's aisle line and the far side, both read from the obstacles
        below = [p for p in polys if p.bounds[1] < 0]
        line = max(p.bounds[3] for p in below)
        far = min(p.bounds[1] for p in polys if p.bounds[1] > line + 1.0)
        assert line == pytest.approx(0.0, abs=1e-9)
        assert far - line == pytest.approx(row["factor"] * row["reference_m"], abs=1e-9, rel=0)
        # the bay: the goal lies behind the aisle line, between the parked cars on either side
        assert goal_body.bounds[3] < line
        axis = np.array([math.cos(goal[2]), math.sin(goal[2])])
        across = np.array([-axis[1], axis[0]])
        neighbours = sorted((p for p in below if abs(p.area - (L + f + b) * w) < 1e-6),
                            key=lambda p: float(np.dot(np.asarray(p.centroid.coords[0]) - goal[:2], across)))
        side = [float(np.dot(np.asarray(p.centroid.coords[0]) - goal[:2], across)) for p in neighbours]
        left = min(s for s in side if s > 0)
        right = max(s for s in side if s < 0)
        bay = w + P.BAY_EXTRA_WIDTH
        assert left == pytest.approx(bay, abs=1e-9) and right == pytest.approx(-bay, abs=1e-9)
        if row["kind"] == "perpendicular":
            assert goal[2] == pytest.approx(math.pi / 2)          # reverse-in: nose to the aisle
            assert row["reference_m"] == pytest.approx(
                math.hypot(R + w / 2, L + f) - math.sqrt((R - w / 2) ** 2 - (R - (bay - w / 2)) ** 2), abs=1e-9)
        else:
            deg = int(row["kind"][-2:])
            assert goal[2] == pytest.approx(-math.radians(deg))   # nose in, turning off the aisle
        assert start[1] == pytest.approx((far + line) / 2)


# ---- the benchmark ------------------------------------------------------------------------------------

def test_duration_bound_and_targets():
    from nhstab.bench.parking import duration_bound, target_rate
    from nhstab.models import make_model

    car = make_model("rwd_car")            # 1.5 m/s, 0.6 rad, 1 rad/s
    # 15 m at 1.5 m/s, one cusp: steering 0 -> 0.6, -0.6 -> 0.6 (1.2 s), 0.6 -> 0: 4 x 0.6 s
    assert duration_bound(15.0, 1, car) == pytest.approx(1.5 * (10.0 + 2.4))
    assert duration_bound(0.0, 0, car) == pytest.approx(1.5 * 1.2)
    assert [target_rate("parallel", f) for f in (0.9, 1.0, 1.05, 1.1, 1.4)] == [0.5, 0.9, 0.9, 1.0, 1.0]
    assert target_rate("perpendicular", 1.1) == 1.0 and target_rate("angled45", 1.5) == 1.0


def test_bench_parking_command_writes_json(tmp_path):
    out = tmp_path / "parking.json"
    res = CliRunner().invoke(cli, ["bench", "parking", "--seeds", "2", "--case", "angled60_rwd_car_aisle200",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    (row,) = data["rows"]
    assert row["name"] == "angled60_rwd_car_aisle200" and len(row["trials"]) == 2
    assert [t["seed"] for t in row["trials"]] == [0, 1]
    assert data["gain_bound"] == 50.0 and data["budget_s"] == 5.0
    for t in row["trials"]:
        if t["status"] == "ok":
            assert t["duration_bound_s"] > 0 and t["cusps"] >= 0 and t["max_gain_norm"] > 0
            assert t["max_abs_steering_rad"] <= 0.6 + 1e-9
    assert row["success_met"] == (row["success_rate"] == 1.0 and row["median_time_s"] < 1.0)
    ok = [t for t in row["trials"] if t["ok_within_budget"]]
    assert row["bounds_met"] == all(t["duration_s"] <= t["duration_bound_s"] and t["max_gain_norm"] <= 50.0
                                    and t["max_abs_steering_rad"] <= 0.6 + 1e-9 for t in ok)
    assert row["met"] == (row["success_met"] and row["bounds_met"])
    from nhstab.bench.parking import summary_lines

    assert "angled60_rwd_car_aisle200" in summary_lines(data)[0]


def test_bench_parking_refuses_unknown_cases():
    res = CliRunner().invoke(cli, ["bench", "parking", "--case", "nope", "--out", "/dev/null"])
    assert res.exit_code == 2 and "'case'" in res.output


@pytest.mark.parametrize("folder, per, gains", [("study", "second", "default"), ("study_per_metre", "metre", "default"),
                                                ("study_per_metre_auto", "metre", "auto"),
                                                ("study_tvlqr_footprint", "second", "default")])
def test_the_committed_parking_study_covers_the_suite_with_both_laws_at_the_target_noise(folder, per, gains):
    """results/parking/study*/ (nhstab parking study; per second, per metre, per metre with --gains auto):
    every case of the suite, planned, the gramian law and TVLQR at its noise levels (which include x1,
    where the targets are judged), 50 trials and a tube check of 10 x N runs per cell; its targets
    recomputed from its cells agree with what it says. Per metre with --gains auto every cell meets its
    success target, as docs/guide/tubes.md says; per second not."""
    from nhstab.batch.parking_study import targets
    from nhstab.records import read_json, record_file

    result = read_json(record_file(ROOT / "results" / "parking" / folder, "study.json"))
    assert result.get("process_per", "second") == per and result["planning"].get("gains", "default") == gains
    assert result["targets"]["success"]["met"] == (folder == "study_per_metre_auto")
    rows = {r["name"]: r for r in P.read_suite_csv(FOLDER / "suite.csv")}
    assert {c["map"] for c in result["cases"]} == set(rows)
    assert all(c["plan"]["found"] for c in result["cases"])
    for case in result["cases"]:
        cells = {(c["controller"], c["noise"]) for c in case["cells"]}
        assert cells == {(k, v) for k in ("gramian", "tvlqr") for v in result["noise_levels"]}
        for c in case["cells"]:
            assert c["trials"]["trials"] == 50 and c["tube_check"]["mc_runs"] == 10 * result["rollouts"]
    assert result["criteria"]["target_noise"] in result["noise_levels"]
    assert result["planning"]["fit"] is True
    assert targets(result) == result["targets"]


def test_the_study_with_tvlqr_on_the_outline_changes_tvlqr_alone():
    """results/parking/study_tvlqr_footprint (--tvlqr-q footprint) against results/parking/study (the same
    command without it): the same plans, and the gramian law's cells equal number for number (same seeds);
    TVLQR's are another law's (its gains from the car's outline), recorded as such."""
    from nhstab.records import read_json, record_file

    base = read_json(record_file(ROOT / "results" / "parking" / "study", "study.json"))
    fp = read_json(record_file(ROOT / "results" / "parking" / "study_tvlqr_footprint", "study.json"))
    assert fp["planning"]["tvlqr_q"] == "footprint" and "tvlqr_q" not in base["planning"]
    assert "--tvlqr-q footprint" in (ROOT / "results" / "parking" / "study_tvlqr_footprint" / "study.md").read_text()
    differ = 0
    for a, b in zip(base["cases"], fp["cases"], strict=True):
        assert a["map"] == b["map"] and a["plan"]["duration_s"] == b["plan"]["duration_s"]
        for ca, cb in zip(a["cells"], b["cells"], strict=True):
            assert (ca["controller"], ca["noise"]) == (cb["controller"], cb["noise"])
            if ca["controller"] == "gramian":
                assert ca["trials"] == cb["trials"] and ca["tube"]["certified_clearance_m"] == cb["tube"]["certified_clearance_m"]
            else:
                differ += ca["tube"]["certified_clearance_m"] != cb["tube"]["certified_clearance_m"]
    assert differ == len(base["cases"])


def test_parking_figure_refuses_bad_input():
    res = CliRunner().invoke(cli, ["parking", "figure", "--seeds", "a,b", "--out", "/tmp/x"])
    assert res.exit_code == 2 and "--seeds" in res.output
    res = CliRunner().invoke(cli, ["parking", "figure", "--car", "bus", "--out", "/tmp/x"])
    assert res.exit_code == 2 and "'car'" in res.output
