"""The lattice search over the whole car-with-trailer rig: its primitives against an independent
integration of the model, its heuristic's pieces, and its plans on the bundled tight maps (a tugger
turning out of a 3 m aisle, a rig reversing into a 2.6 m dock bay), checked body by body with shapely."""

import math

import numpy as np
import pytest
import shapely.geometry as sg
from nhstab.collision import CollisionWorld
from nhstab.errors import InputError
from nhstab.maps import load_map
from nhstab.planning import PathOptions, plan
from nhstab.planning.timing import TimingOptions
from nhstab.planning.trailer import (
    JACKKNIFE_FRACTION,
    LATTICE_FIRST_SHARE,
    LATTICE_RUNGS,
    STEER_FRACTION,
    STEER_RUNG_SHARE,
    TIGHT_JACKKNIFE_FRACTION,
    TIGHT_STEER_FRACTION,
    check_configuration,
    lattice_nominal,
    lattice_plan,
)
from nhstab.planning.trailer_search import (
    MIN_PRIMITIVE_STEPS,
    grid_distance,
    inscribed_radius,
    integrate_primitives,
    lattice_search,
    straight_run,
)
from nhstab.robot import default_robot, resolve_robot
from scipy.integrate import solve_ivp
from shapes import shapely_obstacles

AISLE = "maps/trailer/tugger_aisle.yaml"
BAYS = "maps/trailer/dock_bays.yaml"


def _rhs(model, x, u):
    """The car with one trailer written out here (not with nhstab's rhs)."""
    L, d = model.wheelbase, model.hitch_lengths[0]
    _, _, th, phi, th1 = x
    v, w = u
    return [v * math.cos(th), v * math.sin(th), v * math.tan(phi) / L, w, v * math.sin(th - th1) / d]


def test_primitives_follow_the_model(rng):
    """Every primitive's states are the model's under its own knots (inputs linear between them):
    scipy's DOP853 at rtol 1e-11 agrees to 1e-6 at every integrated state; the knots keep the speed and
    the steering rate cap, the states the steering cap."""
    robot = default_robot("car_trailer")
    model = robot.model
    K = 12
    x0 = np.column_stack([rng.uniform(-5, 5, K), rng.uniform(-5, 5, K), rng.uniform(-3, 3, K),
                          rng.uniform(-0.4, 0.4, K), np.zeros(K)])
    x0[:, 4] = x0[:, 2] - rng.uniform(-0.5, 0.5, K)
    u0 = np.column_stack([rng.choice([-0.9, 0.0, 0.9], K), np.zeros(K)])
    targets = rng.uniform(-0.7, 0.7, K)
    dirs = rng.choice([-1.0, 1.0], K)
    steer_cap, rate_cap, step = 0.54, 0.9, 0.1
    states, knots = integrate_primitives(model, x0, u0, targets, dirs, speed=0.9, steer_cap=steer_cap,
                                         rate_cap=rate_cap, step_s=step)
    sub = (states.shape[1] - 1) // (knots.shape[1] - 1)
    t_states = np.arange(states.shape[1]) * step / sub
    t_knots = np.arange(knots.shape[1]) * step
    for k in range(K):
        def f(t, x, k=k):
            return _rhs(model, x, [np.interp(t, t_knots, knots[k, :, 0]), np.interp(t, t_knots, knots[k, :, 1])])
        sol = solve_ivp(f, (0.0, t_knots[-1]), x0[k], method="DOP853", rtol=1e-11, atol=1e-12, t_eval=t_states,
                        max_step=step / 4)
        np.testing.assert_allclose(states[k], sol.y.T, atol=1e-6)
        np.testing.assert_allclose(np.abs(knots[k, 1:, 0]), 0.9)
        np.testing.assert_array_equal(np.sign(knots[k, 1:, 0]), dirs[k])
    assert np.abs(knots[:, :, 1]).max() <= rate_cap + 1e-12
    assert np.abs(states[:, :, 3]).max() <= steer_cap


def test_heuristic_pieces():
    """The trailer footprint's inscribed radius about its axle (shapely), and the grid distance: in an
    empty world between the octile and the Euclidean distance (one cell's slack)."""
    robot = default_robot("car_trailer")
    fp = robot.footprints[1]
    poly = sg.Polygon(fp.vertices)
    assert inscribed_radius(fp) == pytest.approx(poly.exterior.distance(sg.Point(0, 0)), abs=1e-12)
    world = CollisionWorld([], bounds=(0.0, 0.0, 30.0, 20.0))
    dist, x0, y0 = grid_distance(world, robot, 0.2, (5.0, 5.0), cell=0.25)
    ys, xs = np.mgrid[0:dist.shape[0], 0:dist.shape[1]]
    cx, cy = x0 + (xs + 0.5) * 0.25, y0 + (ys + 0.5) * 0.25
    gx, gy = 5.125, 5.125                                   # the goal cell's centre
    euclid = np.hypot(cx - gx, cy - gy)
    inner = np.isfinite(dist)
    assert inner.sum() > 0.5 * dist.size
    assert np.all(dist[inner] >= euclid[inner] - 1e-9)
    assert np.all(dist[inner] <= 1.0824 * euclid[inner] + 1e-9)     # octile: at most sec(22.5 deg) longer


def test_timeout_reports_the_closest_node():
    """A budget too short for the dock: no plan, and the message names the closest node with numbers."""
    m = load_map(BAYS)
    robot = resolve_robot(None, m.robot, "car_trailer")
    world = CollisionWorld.from_map(m, "known")
    s, g = m.start.as_array(), m.goal.as_array()
    xs, xg = np.array([*s, 0.0, s[2]]), np.array([*g, 0.0, g[2]])
    res = lattice_search(world, robot, xs, xg, margin=0.2, speed=0.9, step_s=0.1, hitch_cap=0.8, steer_cap=0.54,
                         rate_cap=0.9, max_speed=1.5, budget_s=0.2, from_goal=True)
    assert not res.found
    assert "closest node: the trailer's axle" in res.message and "m from the start's" in res.message
    assert res.info["closest_m"] > 0.0 and res.info["expansions"] >= 1


def _bodies(robot, x):
    """The car's and the trailer's polygons at state x, placed here from the columns and the hitch length."""
    d = robot.model.hitch_lengths[0]
    car = (x[0], x[1], x[2])
    trailer = (x[0] - d * math.cos(x[4]), x[1] - d * math.sin(x[4]), x[4])
    return [sg.Polygon(fp.outline_at(p)) for fp, p in zip(robot.footprints, (car, trailer))]


def _configs(m, robot, world):
    s, g = m.start.as_array(), m.goal.as_array()
    xs, xg = np.array([*s, 0.0, s[2]]), np.array([*g, 0.0, g[2]])
    clearances = {"start": check_configuration(m, robot, robot.configuration(s), "start", world),
                  "goal": check_configuration(m, robot, robot.configuration(g), "goal", world)}
    return xs, xg, clearances


@pytest.fixture(scope="module", params=[AISLE, BAYS], ids=["aisle_turn", "reverse_dock"])
def tight_plan(request):
    """The lattice search itself on the tight maps (`plan` runs it where the trailer's Reeds-Shepp paths
    fail; whether they do depends on OMPL's time budget)."""
    m = load_map(request.param)
    robot = resolve_robot(None, m.robot, "car_trailer")
    world = CollisionWorld.from_map(m, "known")
    xs, xg, clearances = _configs(m, robot, world)
    opts = PathOptions(seed=0).for_robot(robot).validated()
    status, message, path, nominal, metrics = lattice_plan(world, robot, opts, TimingOptions(), xs, xg, clearances,
                                                           budget=20.0)
    return request.param, m, robot, status, message, nominal, metrics


def _check_nominal(m, robot, nom, hitch_fraction=JACKKNIFE_FRACTION, steer_fraction=STEER_FRACTION):
    """Starts at the start, ends at the goal, a motion of the model (multiple shooting), the hitch angle
    within the planner's fraction of the jackknife limit, the steering within its cap, and every body
    at every sample clear of every obstacle by the margin (shapely, 1 cm tolerance)."""
    model = robot.model
    s, g = m.start.as_array(), m.goal.as_array()
    np.testing.assert_allclose(nom.x[0], [*s, 0.0, s[2]], atol=1e-9)
    np.testing.assert_allclose(model.state_error(nom.x[-1], [*g, 0.0, g[2]]), 0.0, atol=1e-6)
    assert nom.feasibility_residual() < 1e-5
    assert np.abs(model.hitch_angles(nom.x)).max() <= hitch_fraction * model.jackknife_limit + 1e-6
    assert np.abs(nom.x[:, 3]).max() <= steer_fraction * model.max_steer + 1e-6
    assert np.all(np.abs(nom.u[:, 0]) <= model.max_speed + 1e-9)
    obstacles = shapely_obstacles(m)
    worst = min(min(poly.distance(obstacles) for poly in _bodies(robot, x)) for x in nom.x)
    assert worst >= robot.margin - 0.01


def test_tight_maps_plan_with_the_lattice(tight_plan):
    """The lattice search plans the tugger's 90-degree turn out of a 3 m aisle (forward) and the rig's
    reverse into a 2.6 m dock bay; the nominals pass :func:`_check_nominal`."""
    name, m, robot, status, message, nom, metrics = tight_plan
    assert status == "ok", message
    _check_nominal(m, robot, nom)
    if name == BAYS:                     # into the bay in reverse, rooted at the bay (the tighter end)
        assert nom.u[-5:, 0].max() < 0 and metrics["lattice_rooted_at"] == "goal"
    else:                                # out of the aisle forward
        assert nom.u[-5:, 0].min() > 0 and metrics["lattice_rooted_at"] == "start"


def test_plan_reverses_into_the_dock_bay():
    """`plan` on the dock bays (its Reeds-Shepp paths, then the lattice search where they fail): a plan
    that passes :func:`_check_nominal` and ends reversing."""
    m = load_map(BAYS)
    robot = resolve_robot(None, m.robot, "car_trailer")
    res = plan(m, robot, m.start.as_array(), m.goal.as_array(), PathOptions(seed=0, time_limit_s=10.0))
    assert res.ok, res.message
    _check_nominal(m, robot, res.nominal)
    assert res.nominal.u[-5:, 0].max() < 0


def test_plan_reports_both_searches_when_neither_finds_a_path(tmp_path):
    """The dock bays off an aisle narrowed to 6.5 m: the rig cannot pull out of the bay and turn. `plan`
    says so in one message: the Reeds-Shepp paths, then the lattice search from each end with its
    closest node."""
    text = open(BAYS).read().replace("center: [20.0, 2.5], size: [40.0, 5.0]", "center: [20.0, 3.25], size: [40.0, 6.5]")
    p = tmp_path / "narrow.yaml"
    p.write_text(text)
    m = load_map(p)
    robot = resolve_robot(None, m.robot, "car_trailer")
    res = plan(m, robot, m.start.as_array(), m.goal.as_array(), PathOptions(seed=0, time_limit_s=2.0))
    assert res.status == "no_path"
    assert "lattice search (from the goal" in res.message and "lattice search (from the start" in res.message
    runs = res.metrics["lattice_runs"]
    assert runs[0] == "goal 0" and runs[-1].startswith("start") and len(runs) <= 2 * len(LATTICE_RUNGS)
    assert res.message.count("closest node: the trailer's axle") == len(runs)
    assert "the trailer's Reeds-Shepp paths" in res.message
    # the aisle is tight for the Reeds-Shepp radius: the lattice search runs first
    assert res.metrics["tight_space"] and res.metrics["search_order"][0] == "lattice"
    assert res.metrics["path_attempts"][0] == "no_path (lattice)"
    # the phases share the time limit; the lattice's first root gets its share of the lattice's budget (its
    # later rungs what the earlier left of it), the second root what the first left
    budgets = res.metrics["search_budget_s"]
    assert sum(budgets.values()) <= 2.0 + 1e-9 and budgets["lattice"] > 0.0
    given = res.metrics["lattice_budgets_s"]
    share = LATTICE_FIRST_SHARE * budgets["lattice"]
    assert len(given) == len(runs) and given[0] == pytest.approx(share, rel=1e-12)
    first = [g for g, r in zip(given, runs) if r.startswith("goal")]
    assert all(0.0 < g < b for g, b in zip(first[1:], first)) and first[-1] <= share
    assert 0.0 < given[-1] <= budgets["lattice"]


class _Ticks:
    """A clock that advances ``tick`` seconds at every reading (counts the search's readings)."""

    def __init__(self, tick):
        self.tick, self.now, self.readings = tick, 0.0, 0

    def __call__(self):
        self.now += self.tick
        self.readings += 1
        return self.now


@pytest.mark.parametrize("budget", [0.05, 0.4])
def test_lattice_search_stops_at_its_budget(budget):
    """The search counts its budget on its clock: it stops at the first reading at or past the budget, so
    the time it reports is within one reading of the budget, and it expands at most one node per reading
    (the root's expansion, which always runs, without one)."""
    m = load_map(BAYS)
    robot = resolve_robot(None, m.robot, "car_trailer")
    world = CollisionWorld.from_map(m, "known")
    s, g = m.start.as_array(), m.goal.as_array()
    xs, xg = np.array([*s, 0.0, s[2]]), np.array([*g, 0.0, g[2]])
    clock = _Ticks(0.01)
    res = lattice_search(world, robot, xs, xg, margin=0.2, speed=0.9, step_s=0.1, hitch_cap=0.8, steer_cap=0.54,
                         rate_cap=0.9, max_speed=1.5, budget_s=budget, from_goal=True, clock=clock)
    assert not res.found and f"the budget of {budget:.3g} s ran out" in res.message
    assert budget <= res.info["search_time_s"] <= budget + 2 * clock.tick + 1e-12
    assert res.info["budget_s"] == budget
    assert 1 <= res.info["expansions"] <= round(budget / clock.tick) + 1


def test_straight_run_stops_at_the_aisle_wall():
    """Off a 1.5 S aisle the rig standing straight on the bay's axis leaves the free space before the
    heuristic's 8 m: :func:`straight_run` returns the last step where both bodies keep the margin (shapely),
    and one step more does not; behind the goal, the dock wall, it returns one step."""
    m = load_map("example:trailer_dock_bay150_aisle150")
    robot = resolve_robot(None, m.robot, "car_trailer")
    world = CollisionWorld.from_map(m, "known")
    g = m.goal.as_array()
    xg = np.array([*g, 0.0, g[2]])
    margin, step = 0.05, 0.25
    ahead = straight_run(world, robot, xg, -1.0, margin, 8.0, step)
    assert 1.5 <= ahead < 8.0
    obstacles = shapely_obstacles(m)

    def clearance(s):
        x = xg.copy()
        x[:2] += s * np.array([math.cos(g[2]), math.sin(g[2])])
        return min(poly.distance(obstacles) for poly in _bodies(robot, x))

    assert clearance(ahead) >= margin - 1e-6
    assert clearance(ahead + step) < margin + 1e-6
    assert straight_run(world, robot, xg, 1.0, margin, 8.0, step) == step


def test_a_cut_primitive_is_the_shorter_primitive(rng):
    """The search keeps a primitive that collides up to its last knot before the collision: that prefix is
    the primitive of the same law with fewer knots (a knot's command depends on the states before it only),
    so the states and knots of a primitive of k knots are those of the full one's first k (to rounding)."""
    model = default_robot("car_trailer").model
    K = 8
    x0 = np.column_stack([rng.uniform(-5, 5, K), rng.uniform(-5, 5, K), rng.uniform(-3, 3, K),
                          rng.uniform(-0.4, 0.4, K), np.zeros(K)])
    x0[:, 4] = x0[:, 2] - rng.uniform(-0.5, 0.5, K)
    u0 = np.column_stack([rng.choice([-0.9, 0.9], K), np.zeros(K)])
    targets, dirs = rng.uniform(-0.7, 0.7, K), rng.choice([-1.0, 1.0], K)
    kw = dict(speed=0.9, steer_cap=0.54, rate_cap=0.9, step_s=0.1)
    full, kfull = integrate_primitives(model, x0, u0, targets, dirs, steps=12, **kw)
    sub = (full.shape[1] - 1) // 12
    for k in (MIN_PRIMITIVE_STEPS, 7):
        part, kpart = integrate_primitives(model, x0, u0, targets, dirs, steps=k, **kw)
        np.testing.assert_allclose(part, full[:, :k * sub + 1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(kpart, kfull[:, :k + 1], rtol=0, atol=1e-12)


def _dock(name):
    m = load_map(f"example:{name}")
    robot = resolve_robot(None, m.robot, "car_trailer")
    world = CollisionWorld.from_map(m, "known")
    xs, xg, clearances = _configs(m, robot, world)
    return m, robot, world, xs, xg, clearances


def _rung_plan(name, rung, expansions):
    """The lattice search on a suite case, rooted at the bay, on one rung of LATTICE_RUNGS, with a budget
    counted in clock readings (one per expansion: machine-independent), and the nominal of its plan."""
    m, robot, world, xs, xg, clearances = _dock(name)
    model = robot.model
    resolution, cut, hitch_f, steer_f, prims = LATTICE_RUNGS[rung]
    margin = robot.margin
    res = lattice_search(world, robot, xs, xg, margin=margin + 0.005, speed=0.9, step_s=0.1,
                         hitch_cap=hitch_f * model.jackknife_limit, steer_cap=steer_f * model.max_steer,
                         rate_cap=steer_f * model.max_steer_rate, max_speed=1.5, budget_s=expansions * 0.01,
                         piece_margin=margin + 0.004, from_goal=True, resolution=resolution, cut_primitives=cut,
                         primitives=prims, clock=_Ticks(0.01))
    nom = None
    if res.found:
        nom, _ = lattice_nominal(robot, res, TimingOptions(), world, margin, xs, xg, 0.9)
    return m, robot, res, nom


def test_cut_primitives_reverse_into_a_bay_of_1_2_widths():
    """A bay 1.2 x the rig's width off an aisle 1.5 x its swept path: on the plan's lattice the rig cannot
    leave the bay (every cell it reaches is expanded, within a few hundred expansions); with primitives cut
    at their first collision it can. The plan ends reversing into the bay and passes _check_nominal (every
    body by shapely, the hitch angle within the plan's fraction of the jackknife limit)."""
    name = "trailer_dock_bay120_aisle150"
    _, _, coarse, _ = _rung_plan(name, 0, 3000)
    assert not coarse.found and coarse.info["exhausted"] and coarse.info["expansions"] < 500
    assert "every reachable cell was expanded" in coarse.message
    m, robot, res, nom = _rung_plan(name, 1, 3000)
    assert res.found and res.info["cut_primitives"], res.message
    _check_nominal(m, robot, nom)
    assert nom.u[-5:, 0].max() < 0


@pytest.mark.slow
def test_the_tight_rung_reverses_into_a_bay_off_a_1_2_swept_path_aisle():
    """A bay 1.5 x the rig's width off an aisle 1.2 x its swept path: both rungs at the plan's caps expand
    every cell they reach; the finer lattice at the tight caps plans. Its nominal passes _check_nominal at
    the tight fractions: every body clear by the margin (shapely), the hitch angle within 0.95 of the
    jackknife limit (so never past it), the steering within its limit."""
    name = "trailer_dock_bay150_aisle120"
    for rung in (0, 1):
        _, _, res, _ = _rung_plan(name, rung, 3000)
        assert not res.found and res.info["exhausted"], res.message
    m, robot, res, nom = _rung_plan(name, 3, 20000)
    assert res.found and res.info["resolution"] == 1, res.message
    _check_nominal(m, robot, nom, TIGHT_JACKKNIFE_FRACTION, TIGHT_STEER_FRACTION)
    assert np.abs(robot.model.hitch_angles(nom.x)).max() < robot.model.jackknife_limit
    assert nom.u[-5:, 0].max() < 0


def _replay(model, x0, knots, step_s):
    """The model written out here (_rhs) from x0 under inputs linear between ``knots``, DOP853 over each
    interval: the state after the last knot."""
    x = np.array(x0, dtype=float)
    for k in range(len(knots) - 1):
        u0, u1 = knots[k], knots[k + 1]
        sol = solve_ivp(lambda t, y: _rhs(model, y, u0 + (t / step_s) * (u1 - u0)), (0.0, step_s), x,
                        method="DOP853", rtol=1e-11, atol=1e-12)
        x = sol.y[:, -1]
    return x


def _steer_rung():
    rung = next(i for i, r in enumerate(LATTICE_RUNGS) if r[4] == "steer")
    assert all(r[4] == "hitch" and not r[0] for r in LATTICE_RUNGS[:rung])   # after the coarse hitch-law rungs
    return rung


@pytest.mark.slow
def test_stop_and_steer_rung_leaves_a_bay_off_a_1_2_swept_path_aisle():
    """A bay 1.3 x the rig's width off an aisle 1.2 x its swept path, where no hitch-law rung planned within
    20,000 expansions: the stop-and-steer rung plans. Its inputs steer only at rest (omega != 0 only where
    v = 0) within the rate cap; replayed through the model written out here they end at the goal (the plan
    is reversed in time from the bay); its nominal passes _check_nominal at the tight fractions and ends
    reversing into the bay."""
    name = "trailer_dock_bay130_aisle120"
    m, robot, res, nom = _rung_plan(name, _steer_rung(), 12000)
    assert res.found and res.info["primitive_kind"] == "steer", res.message
    model = robot.model
    kn = res.knots
    steering = np.abs(kn[:, 1]) > 0
    assert np.all(kn[steering, 0] == 0.0)
    assert np.abs(kn[:, 1]).max() <= TIGHT_STEER_FRACTION * model.max_steer_rate + 1e-12
    assert np.abs(kn[:, 0]).max() <= 0.9 + 1e-12
    # the primitives' end, replayed: the goal (the search drove them away from it; the plan is that reversed)
    _, _, xs, xg, _ = _dock(name)[1:]
    end = _replay(model, res.states[0], kn, res.step_s)
    np.testing.assert_allclose(model.state_error(end, xg), 0.0, atol=1e-6)
    assert res.info["expansions"] < 12000
    _check_nominal(m, robot, nom, TIGHT_JACKKNIFE_FRACTION, TIGHT_STEER_FRACTION)
    assert nom.u[-5:, 0].max() < 0


def test_stop_and_steer_rung_exhausts_a_closed_bay():
    """The 1.1 W bay off the 1.2 S aisle, whose goal `nhstab trailer reach` finds closed at the maps' margin
    (600 cells on its grid): the stop-and-steer rung, on a grid of the same cells (0.1 m, 2 degrees) with
    moves of about 0.3 m, also expands every cell it reaches, within a few thousand expansions, without a
    plan."""
    _, _, res, _ = _rung_plan("trailer_dock_bay110_aisle120", _steer_rung(), 20000)
    assert not res.found and res.info["exhausted"], res.message
    assert res.info["expansions"] < 5000
    assert "stop-and-steer primitives" in res.message and "every reachable cell was expanded" in res.message


def test_the_stop_and_steer_rung_keeps_the_budget_at_an_enclosed_end():
    """Where the hitch-law rungs at the first root (the bay) expand every cell they reach, the stop-and-steer
    rung there may run until STEER_RUNG_SHARE of the lattice's budget has passed, not only the first root's
    LATTICE_FIRST_SHARE: the other root gets at most the rest (or nothing)."""
    m, robot, world, xs, xg, clearances = _dock("trailer_dock_bay130_aisle120")
    opts = PathOptions(seed=0).for_robot(robot).validated()
    budget = 6.0
    status, _, _, _, metrics = lattice_plan(world, robot, opts, TimingOptions(), xs, xg, clearances, budget=budget)
    runs, given = metrics["lattice_runs"], metrics["lattice_budgets_s"]
    assert status == "no_path" and runs[:3] == ["goal 0", "goal 1", "goal 2"]
    # more than the whole root's share (the two rungs before it take well under the 1.8 s between the shares)
    assert given[2] > LATTICE_FIRST_SHARE * budget
    assert all(r.startswith("goal") for r in runs[:-1])
    if runs[-1].startswith("start"):
        assert given[-1] <= (1.0 - STEER_RUNG_SHARE) * budget + 1e-9


def test_an_unknown_primitive_kind_is_refused():
    """lattice_search names its `primitives` argument, what it takes and what it was given."""
    m, robot, world, xs, xg, _ = _dock("trailer_dock_bay150_aisle150")
    with pytest.raises(InputError) as err:
        lattice_search(world, robot, xs, xg, margin=0.05, speed=0.9, step_s=0.1, hitch_cap=0.8, steer_cap=0.54,
                       rate_cap=0.9, max_speed=1.5, budget_s=1.0, primitives="spiral")
    assert err.value.argument == "primitives" and "steer" in err.value.expected and err.value.got == "spiral"
