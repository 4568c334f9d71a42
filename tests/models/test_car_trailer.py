"""The car with trailers (``car_trailer``): its equations against independent derivations, its
parameters, the robot description's list-valued parameters and trailer footprints, and the
multi-body collision queries against shapely."""

import math

import numpy as np
import pytest
import shapely.geometry as sg
from hypothesis import given, settings
from hypothesis import strategies as st
from nhstab import bodies
from nhstab.collision import CollisionWorld
from nhstab.errors import InputError
from nhstab.maps import load_map
from nhstab.models import make_model
from nhstab.robot import default_robot, robot_from_spec
from reference import central_jacobian
from scipy.integrate import solve_ivp

angle = st.floats(-3.0, 3.0, allow_nan=False)
hitch = st.floats(-1.2, 1.2, allow_nan=False)




@settings(max_examples=40, deadline=None)
@given(th=angle, phi=st.floats(-1.2, 1.2), hitches=st.lists(hitch, min_size=3, max_size=3),
       v=st.floats(-2, 2), w=st.floats(-2, 2))
def test_three_trailers_jacobian_matches_central_differences(th, phi, hitches, v, w):
    """The contract test runs over the registered default (one trailer); the recursion for N = 3."""
    m = make_model("car_trailer", hitch_lengths=[2.0, 3.5, 1.5])
    heads = th - np.cumsum(hitches)
    x = np.array([1.0, -2.0, th, phi, *heads])
    u = np.array([v, w])
    np.testing.assert_allclose(m.dgu_dx(x, u), central_jacobian(lambda z: m.g(z) @ u, x), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(m.rhs(x, u), m.g(x) @ u, rtol=1e-13, atol=1e-14)


def test_trailer_axles_never_slip_sideways(rng):
    """Independent check of the N-trailer equations: integrate the model, differentiate every
    trailer's axle position (body_poses) numerically, and the velocity must lie along the trailer's
    heading (no sideways slip), and every hitch bar keep its length."""
    m = make_model("car_trailer", hitch_lengths=[2.0, 3.0])
    x0 = np.array([0.0, 0.0, 0.3, 0.1, 0.1, -0.1])

    def u(t):
        return np.array([1.0 + 0.5 * math.sin(t), 0.4 * math.cos(1.3 * t)])

    sol = solve_ivp(lambda t, x: m.rhs(x, u(t)), (0, 8), x0, method="DOP853", rtol=1e-12, atol=1e-12,
                    dense_output=True)
    t = np.linspace(0.5, 7.5, 30)
    h = 1e-5
    poses = m.body_poses(sol.sol(t).T)
    vel = (m.body_poses(sol.sol(t + h).T)[..., :2] - m.body_poses(sol.sol(t - h).T)[..., :2]) / (2 * h)
    for b in range(1, 3):
        normal = np.column_stack([-np.sin(poses[:, b, 2]), np.cos(poses[:, b, 2])])
        np.testing.assert_allclose(np.einsum("ij,ij->i", vel[:, b], normal), 0.0, atol=1e-7)
        bar = np.hypot(*(poses[:, b - 1, :2] - poses[:, b, :2]).T)
        np.testing.assert_allclose(bar, m.hitch_lengths[b - 1], rtol=1e-12)


def test_one_trailer_equation_and_steady_turn():
    """theta1' = (v / d) sin(theta - theta1); on a steady turn at the smallest radius the car steers
    at its limit or the hitch sits at its jackknife limit, and the trailer axle circles at
    min_turning_radius."""
    m = make_model("car_trailer", hitch_lengths=[3.0])
    x = np.array([0.0, 0.0, 0.7, 0.2, 0.4])
    np.testing.assert_allclose(m.rhs(x, np.array([1.3, 0.0]))[4], 1.3 / 3.0 * math.sin(0.3), rtol=1e-14)
    R1 = m.min_turning_radius
    R0 = math.hypot(R1, 3.0)
    D = math.atan(3.0 / R1)
    phi = math.atan(m.wheelbase / R0)
    assert phi <= m.max_steer + 1e-12 and D <= m.jackknife_limit + 1e-12
    assert math.isclose(phi, m.max_steer, rel_tol=1e-9) or math.isclose(D, m.jackknife_limit, rel_tol=1e-9)
    # the steady state holds: theta' = theta1'
    xs = np.array([0.0, 0.0, D, phi, 0.0])
    f = m.rhs(xs, np.array([1.0, 0.0]))
    assert f[2] == pytest.approx(f[4], rel=1e-12)


def test_body_poses_and_hitch_angles():
    m = make_model("car_trailer", hitch_lengths=[2.0, 3.0])
    x = np.array([1.0, 2.0, 0.5, 0.1, 0.2, -0.3])
    p = m.body_poses(x)
    np.testing.assert_allclose(p[1], [1 - 2 * math.cos(0.2), 2 - 2 * math.sin(0.2), 0.2], rtol=1e-15)
    np.testing.assert_allclose(p[2], [p[1, 0] - 3 * math.cos(-0.3), p[1, 1] - 3 * math.sin(-0.3), -0.3], rtol=1e-15)
    np.testing.assert_allclose(m.hitch_angles(x), [0.3, 0.5], rtol=1e-14)
    assert m.state_names == ("x", "y", "theta", "phi", "theta1", "theta2")
    assert m.angle_states == (2, 3, 4, 5)


@pytest.mark.parametrize("params,argument", [
    ({"hitch_lengths": [0.0]}, "car_trailer.hitch_lengths[0]"),
    ({"hitch_lengths": [2.0, -1.0]}, "car_trailer.hitch_lengths[1]"),
    ({"hitch_lengths": []}, "car_trailer.hitch_lengths"),
    ({"hitch_lengths": [float("nan")]}, "car_trailer.hitch_lengths[0]"),
    ({"jackknife_limit": 1.6}, "car_trailer.jackknife_limit"),
    ({"jackknife_limit": 0.0}, "car_trailer.jackknife_limit"),
    ({"max_steer": 1.6}, "car_trailer.max_steer"),
])
def test_bad_parameters(params, argument):
    with pytest.raises(InputError) as err:
        make_model("car_trailer", **params)
    assert err.value.argument == argument


def test_robot_description_lists_and_trailer_footprints():
    r = robot_from_spec({"model": "car_trailer", "hitch_lengths": [2.5, 3.0],
                         "trailer_footprint": [{"radius": 0.8}, {"rectangle": {"length": 3, "width": 2}}]})
    assert r.model.hitch_lengths == (2.5, 3.0) and r.trailers == 2
    assert len(r.footprints) == 3 and r.footprints[1].radius == 0.8
    again = robot_from_spec(r.spec())              # the spec round-trips, lists included
    assert again.spec() == r.spec()
    one = robot_from_spec({"model": "car_trailer", "hitch_lengths": [2.5, 3.0], "trailer_footprint": {"radius": 0.7}})
    assert [f.radius for f in one.trailer_footprints] == [0.7, 0.7]
    d = default_robot("car_trailer")
    assert d.turning_radius == pytest.approx(5.0 * d.model.min_turning_radius)
    assert d.configuration([1, 2, 0.3]).tolist() == [1, 2, 0.3, 0.3]          # trailer in line
    assert d.configuration([1, 2, 0.3, 0.1]).tolist() == [1, 2, 0.3, 0.1]
    assert d.configuration([1, 2, 0.3, 0.0, 0.1]).tolist() == [1, 2, 0.3, 0.1]   # a full state, phi = 0
    with pytest.raises(InputError, match="phi = 0.05 rad"):                        # no phi is dropped
        d.configuration([1, 2, 0.3, 0.05, 0.1])


@pytest.mark.parametrize("spec,argument", [
    ({"model": "car_trailer", "hitch_lengths": [0]}, "robot.hitch_lengths[0]"),
    ({"model": "car_trailer", "hitch_lengths": [-2.0]}, "robot.hitch_lengths[0]"),
    ({"model": "car_trailer", "hitch_lengths": "3"}, "robot.hitch_lengths"),
    ({"model": "car_trailer", "hitch_lengths": [2, 2], "trailer_footprint": [{"radius": 1}]}, "robot.trailer_footprint"),
    ({"model": "rwd_car", "trailer_footprint": {"radius": 1}}, "robot.trailer_footprint"),
    ({"model": "car_trailer", "trailer_footprint": {"radius": -1}}, "robot.trailer_footprint.radius"),
    ({"model": "car_trailer", "turning_radius": 1.0}, "robot.turning_radius"),
])
def test_bad_robot_specs(spec, argument):
    with pytest.raises(InputError) as err:
        robot_from_spec(spec)
    assert err.value.argument == argument


def test_configuration_refuses_other_lengths():
    d = default_robot("car_trailer")
    with pytest.raises(InputError) as err:
        d.configuration([1, 2], "goal")
    assert err.value.argument == "goal"


@pytest.fixture(scope="module")
def dock():
    m = load_map("maps/trailer/loading_dock.yaml")
    return m, CollisionWorld.from_map(m, "all")


def test_every_body_is_checked_against_shapely(dock, rng):
    """bodies.clearance / collides / free_many against shapely distances of every body's polygon."""
    m, world = dock
    robot = default_robot("car_trailer")
    obstacles = sg.MultiPolygon([sg.Polygon(o.vertices) for o in m.obstacles if hasattr(o, "vertices")])
    circles = [sg.Point(*o.center).buffer(o.radius, 256) for o in m.obstacles if not hasattr(o, "vertices")]
    xmin, ymin, xmax, ymax = m.bounds
    walls = sg.box(xmin - 1, ymin - 1, xmax + 1, ymax + 1).difference(sg.box(xmin, ymin, xmax, ymax))
    everything = sg.GeometryCollection([obstacles, *circles, walls])
    states = []
    while len(states) < 60:
        x, y, th = rng.uniform(2, 42), rng.uniform(2, 28), rng.uniform(-math.pi, math.pi)
        states.append([x, y, th, 0.0, th + rng.uniform(-0.9, 0.9)])
    states = np.array(states)
    free = bodies.free_many(world, robot, states, 0.2)
    for k, x in enumerate(states):
        dists = []
        for pose, fp in zip(robot.body_poses(x), robot.footprints):
            poly = sg.Polygon(fp.outline_at(pose))
            dists.append(poly.distance(everything) if not poly.intersects(everything) else 0.0)
        c, b = bodies.clearance(world, robot, x)
        shapely_min = min(dists)
        if shapely_min > 0:
            assert c == pytest.approx(shapely_min, abs=2e-4)     # circles are 256-gons in shapely
            assert b == int(np.argmin(dists))
        assert (bodies.collides(world, robot, x) is None) == (shapely_min > 0)
        assert free[k] == (shapely_min > 0.2 + 2e-4) or abs(shapely_min - 0.2) < 2e-4


def test_batch_report_counts_jackknifes_per_cell():
    """The report's trailer table is computed from the trials' own metrics: the jackknife count with its
    Wilson interval, medians that skip missing values; cells of one-body robots get no trailer row."""
    from nhstab.batch.report import _trailer_table, cell_table, wilson

    def trial(cell, k, status, **metrics):
        spec = {"cell_spec": {"map": "dock", "robot": None, "controller": cell, "alpha": None, "delta": None,
                              "gamma": None, "noise": 1.0}}
        return {"cell": cell, "trial": k, "status": status, "spec": spec, "metrics": {"robot": "r", **metrics},
                "timings": {}}

    rig = [trial("rig", 0, "collision", jackknife=True, max_abs_hitch_angle_rad=1.01,
                 final_trailer_position_error_m=9.0),
           trial("rig", 1, "reached", jackknife=False, max_abs_hitch_angle_rad=0.5,
                 final_trailer_position_error_m=0.1),
           trial("rig", 2, "collision", jackknife=True, max_abs_hitch_angle_rad=1.02,
                 final_trailer_position_error_m=None),
           trial("rig", 3, "reached", jackknife=False, max_abs_hitch_angle_rad=float("nan"),
                 final_trailer_position_error_m=0.2)]
    car = [trial("car", k, "reached") for k in range(3)]
    rows = {r["cell"]: r for r in cell_table(rig + car)}
    r = rows["rig"]
    assert r["jackknife_count"] == 2 and r["collision_count"] == 2
    assert (r["jackknife_rate"], r["jackknife_lo"], r["jackknife_hi"]) == wilson(2, 4)
    assert r["max_abs_hitch_angle_rad_median"] == pytest.approx(1.01)         # NaN skipped
    assert r["final_trailer_position_error_m_median"] == pytest.approx(0.2)   # None skipped
    assert "jackknife_rate" not in rows["car"]
    header, table = _trailer_table(list(rows.values()))
    assert len(table) == 1 and len(table[0]) == len(header) and table[0][1].startswith("50% [")
