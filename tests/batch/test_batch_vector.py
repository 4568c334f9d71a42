"""The vectorised shared-nominal engine against the single-run loop it vectorises."""

from __future__ import annotations

import math

import numpy as np
import pytest
from nhstab.batch.vector import simulate_shared
from nhstab.bench import hilare_sinusoid
from nhstab.errors import InputError
from nhstab.execution import ControllerOptions, Plant, RunOptions, build_law, execute, summary
from nhstab.execution.config import NoiseOptions, TubeOptions
from nhstab.execution.seeds import seed_for
from nhstab.maps.base import Map, Pose, box_polygon
from nhstab.models import make_model
from nhstab.nominal import Nominal
from nhstab.paper import CASES
from nhstab.robot import default_footprint, make_robot

SEEDS = [0, 1, 7, 123, 2026]


def _law(nominal: Nominal):
    case = CASES["hilare-sinusoid"]
    return build_law(nominal, ControllerOptions(kind="gramian", alpha=case.alpha, delta=case.delta,
                                                gamma=case.gamma), {})


@pytest.fixture(scope="module")
def hilare():
    """The paper's Hilare sinusoid (2 pi s, grid step 2 pi / 314 = 0.02 s) with the paper case's
    gramian law: 315 control steps at 50 Hz."""
    return _law(hilare_sinusoid(315))


def reference_loop(law, seed, noise, rate_hz=50.0, substeps=4, saturate=True, model=None):
    """CompositeRun.run's tracking loop for one trial, step by step, with its seeded generators:
    returns (status, log arrays t, x, y, x0, u, u0). ``model``: the robot (default the nominal's)."""
    model = model or law.nominal.model
    n, names = model.n, model.state_names
    T = 1.0 / rate_hz
    plant = Plant(model, T, substeps)
    rng_sensor = np.random.default_rng(seed_for(seed, "sensor"))
    rng_process = np.random.default_rng(seed_for(seed, "process"))
    sigma_sensor = noise.vector("sensor", names)
    per_metre = noise.process_per == "metre"
    sigma_process = noise.vector("process", names) * (1.0 if per_metre else math.sqrt(T))
    impulses = noise.impulse_list(names)
    u_lo, u_hi = model.input_limits().T
    sigma0 = noise.vector("initial", names)
    rng0 = np.random.default_rng(seed_for(seed, "initial"))
    draw = rng0.standard_normal(n) if noise.distribution == "gaussian" else rng0.uniform(-1.0, 1.0, n)
    x = np.clip(law.nominal.x[0] + sigma0 * draw, *model.state_limits().T)
    log = {key: [] for key in ("t", "x", "y", "x0", "u", "u0")}

    def record(*values):
        for key, v in zip(log, values):
            log[key].append(v)

    def arrays():
        return {key: np.array(v) for key, v in log.items()}

    zero_u = np.zeros(model.m)
    k = 0
    while True:
        t = k * T
        tau = t - 0.0
        if tau >= law.t_end - 1e-9:
            y = x + sigma_sensor * rng_sensor.standard_normal(n)
            record(t, x.copy(), y, law.reference(tau)[0], zero_u, zero_u)
            return "completed", arrays()
        y = x + sigma_sensor * rng_sensor.standard_normal(n)
        u_ff = law.mean_input(tau, tau + T)
        u, x0, _ = law.control(tau, y, u_ff)
        if saturate:
            u = np.clip(u, u_lo, u_hi)
        if not np.all(np.isfinite(u)):
            return "numerical_failure", arrays()
        record(t, x.copy(), y, x0, u, u_ff)
        moved = plant.step(x, u)
        w = sigma_process * rng_process.standard_normal(n)
        if per_metre:        # std intensity * sqrt(distance the position moved in the period)
            dx, dy = moved[0] - x[0], moved[1] - x[1]
            w = w * np.sqrt(np.sqrt(dx * dx + dy * dy))
        x = moved + w
        t_next = (k + 1) * T
        while impulses and impulses[0][0] < t_next - 1e-12:
            x = x + impulses.pop(0)[1]
        if not np.all(np.isfinite(x)):
            return "numerical_failure", arrays()
        k += 1


def _assert_trial_is(res, i, status, log):
    """Trial i of a SharedResult equals a loop's log sample for sample (NaN after a failure)."""
    assert res.status[i] == status
    L = len(log["t"])
    for key, mine in (("x", res.x), ("y", res.y), ("u", res.u)):
        assert np.array_equal(mine[i, :L], log[key]), key
        assert np.all(np.isnan(mine[i, L:])), key
    assert np.array_equal(res.t[:L], log["t"])
    assert np.array_equal(res.x0[:L], log["x0"])
    assert np.array_equal(res.u_ff[:L], log["u0"])


# ---- the building blocks are exact ------------------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 99, 2**40 + 3])
def test_a_block_draw_is_the_successive_draws(seed):
    """numpy's Generator fills a (S, n) block in the order of S successive draws of n values (this
    numpy: the engine relies on it for bit-identity)."""
    for stream in ("sensor", "process", "initial"):
        block = np.random.default_rng(seed_for(seed, stream)).standard_normal((316, 3))
        rng = np.random.default_rng(seed_for(seed, stream))
        assert np.array_equal(block, np.array([rng.standard_normal(3) for _ in range(316)]))
    block = np.random.default_rng(seed_for(seed, "initial")).uniform(-1.0, 1.0, (50, 4))
    rng = np.random.default_rng(seed_for(seed, "initial"))
    assert np.array_equal(block, np.array([rng.uniform(-1.0, 1.0, 4) for _ in range(50)]))


def test_the_stacked_gain_product_and_plant_step_are_the_per_trial_ones(rng):
    """np.matmul over a (K, n, 1) stack calls the same BLAS matrix-vector product per trial as
    ``K @ e`` (a (K, n) @ (n, m) product or an elementwise sum would not be bit-identical), and
    Plant.step on a (K, n) stack treats each row as it treats one state."""
    K = rng.standard_normal((2, 3))
    E = rng.standard_normal((500, 3)) * 10.0 ** rng.integers(-6, 3, (500, 1))
    assert np.array_equal(np.matmul(K, E[:, :, None])[:, :, 0], np.array([K @ e for e in E]))
    for name, n in (("unicycle", 3), ("rwd_car", 4), ("fwd_car", 4), ("car_trailer", 5)):
        plant = Plant(make_model(name), 0.02, 4)
        X = rng.uniform(-3.0, 3.0, (300, n))
        U = rng.uniform(-2.0, 2.0, (300, 2))
        assert np.array_equal(plant.step(X, U), np.array([plant.step(x, u) for x, u in zip(X, U)])), name


@pytest.mark.parametrize("name", ["unicycle", "rwd_car", "fwd_car", "car_trailer", "heisenberg"])
@pytest.mark.parametrize("substeps", [4, 1, 3])
def test_the_stack_stepper_is_the_step_on_every_column(name, substeps, rng):
    """Plant.stack_stepper (state-major, the engine's) gives Plant.step's result bit for bit (the
    sign of a zero included), column by column and for single states, at the steering limits and
    with non-finite states and inputs, called again on the same work arrays."""
    model = make_model(name)
    plant = Plant(model, 0.02 * substeps / 4, substeps)
    K = 1001
    x = rng.uniform(-3.0, 3.0, (K, model.n)) * 10.0 ** rng.integers(-6, 2, (K, 1))
    u = rng.uniform(-2.0, 2.0, (K, model.m)) * 10.0 ** rng.integers(-6, 2, (K, 1))
    lim = model.state_limits()
    x[:100] = np.clip(x[:100] * 100.0, lim[:, 0], lim[:, 1])
    x[100:110], u[110:120], x[120:130], u[130:140], x[140:150], u[150:160] = np.nan, np.inf, 1e300, 0.0, -0.0, -0.0
    step = plant.stack_stepper(K)
    with np.errstate(all="ignore"):
        ref = plant.step(x, u)
        single = np.array([plant.step(a, b) for a, b in zip(x[::50], u[::50])])
        for _ in range(2):
            got = step(np.ascontiguousarray(x.T), np.ascontiguousarray(u.T), np.empty((model.n, K))).T
            assert np.array_equal(got.view(np.uint64), ref.view(np.uint64))
    assert np.array_equal(got[::50], single, equal_nan=True)


def test_elementwise_functions_do_not_depend_on_the_layout(rng):
    """What the state-major engine relies on (this numpy, this machine): float64 sin, cos, tan,
    remainder and clip give an element the same value in a large contiguous array, a strided column,
    a short array and a 0-d one (the single run's). And the wrap's shortcut: for a = e + pi in
    [0, 2 pi) (-0.0 included), a % (2 pi) - pi is a - pi."""
    a = np.concatenate([rng.uniform(-4.0, 4.0, 40000), rng.standard_normal(10000) * 10.0 ** rng.integers(-9, 3, 10000),
                        [0.0, -0.0, 0.6, -0.6, math.pi, 1e300, np.inf, np.nan, 5e-324]])
    cols = np.repeat(a[:, None], 4, axis=1)
    with np.errstate(all="ignore"):
        for f in (np.sin, np.cos, np.tan, lambda v: v % (2.0 * math.pi), lambda v: np.clip(v, -0.6, 0.6)):
            ref = f(a)
            assert np.array_equal(f(cols[:, 2]), ref, equal_nan=True)
            assert np.array_equal(f(a[:48000].reshape(16, -1)).ravel(), ref[:48000], equal_nan=True)
            assert np.array_equal(np.concatenate([f(a[i:i + 7]) for i in range(0, len(a), 7)]), ref, equal_nan=True)
            assert np.array_equal(np.array([f(a[i:i + 1].reshape(())) for i in range(0, len(a), 37)]), ref[::37],
                                  equal_nan=True)
    two_pi = 2.0 * math.pi
    w = np.concatenate([rng.uniform(0.0, two_pi, 100000), [0.0, -0.0, np.nextafter(two_pi, 0.0), 5e-324]])
    assert np.all((w >= 0.0) & (w < two_pi))
    assert np.array_equal((w % two_pi - math.pi).view(np.uint64), (w - math.pi).view(np.uint64))


@pytest.mark.parametrize("seed", [0, 12345])
def test_drawing_into_rows_in_blocks_is_the_block_draw(seed):
    """The engine fills a trial's rows of a preallocated array block after block (out=): the same
    values as one block draw, which is the loop's successive draws (above)."""
    block = np.random.default_rng(seed_for(seed, "sensor")).standard_normal((316, 3))
    rng = np.random.default_rng(seed_for(seed, "sensor"))
    buf = np.empty((2, 100, 3))
    parts = []
    for size in (100, 100, 100, 16):
        rng.standard_normal(out=buf[1, :size])
        parts.append(buf[1, :size].copy())
    assert np.array_equal(np.concatenate(parts), block)
    rng0 = np.random.default_rng(seed_for(seed, "initial"))
    rng0.standard_normal(out=buf[0, 7])
    assert np.array_equal(buf[0, 7], np.random.default_rng(seed_for(seed, "initial")).standard_normal(3))


def test_the_generators_are_the_runs_own(monkeypatch):
    """The engine seeds its generators with SeedSequence words computed for all seeds at once: the
    words of seed_for's SeedSequence (seeds below and above 2**32, every stream), so the same draws
    as the run's default_rng(seed_for(...)); if they were not, it would notice and seed the slow way."""
    from nhstab.batch import vector
    from nhstab.execution.seeds import _SEED_STREAMS

    rng = np.random.default_rng(8)
    seeds = np.array([0, 1, 7, 2**32 - 1, 2**32, 2**40 + 3, 2**63 - 1, *rng.integers(0, 2**63 - 1, 200),
                      *rng.integers(0, 2**32, 200)], dtype=np.int64)
    for stream, index in _SEED_STREAMS.items():
        words = vector._seed_words(seeds, index)
        assert np.array_equal(words, [seed_for(int(s), stream).generate_state(4, np.uint64) for s in seeds]), stream

    def same_draws(stream, some):
        for gen, seed in zip(vector._generators(some, stream), some):
            run = np.random.default_rng(seed_for(int(seed), stream))
            assert np.array_equal(gen.standard_normal(7), run.standard_normal(7))

    same_draws("sensor", seeds[::20])
    monkeypatch.setattr(vector, "_seed_words", lambda s, stream: np.zeros((len(s), 4), dtype=np.uint64))
    same_draws("process", seeds[:5])


@pytest.mark.parametrize("rate_hz", [50.0, 30.0, 17.0, 8.0])
def test_the_schedule_is_the_laws_own_reference_gain_and_mean_input(hilare, rate_hz):
    """_shared evaluates x0, K and the held mean input of all samples at once with the law's own
    arithmetic: bit-identical to reference, gain and mean_input called one time at a time (also
    where a hold interval spans several grid points, and at the end sample past the nominal)."""
    from nhstab.batch.vector import _shared

    T = 1.0 / rate_hz
    for t_stop in (hilare.t_end, 1.37):
        sh = _shared(hilare, T, t_stop, [])
        taus = [k * T for k in range(len(sh.t))]
        assert np.array_equal(sh.t, taus)
        x0 = np.array([hilare.reference(tau)[0] for tau in taus])
        u_ff = np.array([hilare.mean_input(tau, tau + T) for tau in taus[:-1]] + [np.zeros(2)])
        K = np.array([hilare.gain(tau) for tau in taus[:-1]])
        for mine, ref in ((sh.x0, x0), (sh.u_ff, u_ff), (sh.K, K)):
            assert np.array_equal(mine.view(np.uint64), ref.view(np.uint64))


# ---- equivalence with the loop ----------------------------------------------------------------------

@pytest.mark.parametrize("noise", [
    NoiseOptions(),
    NoiseOptions(scale=2.0, distribution="uniform", impulses=((1.5, {"y": 0.3}), (0.0, {"theta": -0.2}),
                                                               (1.51, {"x": 0.1}))),
    NoiseOptions(scale=2.0, process_per="metre", impulses=((1.5, {"y": 0.3}),)),
], ids=["default", "uniform-impulses", "per-metre"])
def test_bit_identical_to_the_single_run_loop(hilare, noise):
    res = simulate_shared(hilare, SEEDS, noise)
    assert res.x.shape == (5, 316, 3) and res.u.shape == (5, 316, 2) and res.t.shape == (316,)
    for i, seed in enumerate(SEEDS):
        status, log = reference_loop(hilare, seed, noise)
        _assert_trial_is(res, i, status, log)
        assert np.array_equal(res.e[i], make_model("unicycle").state_error(log["x"], log["x0"]))
    assert np.all(res.completed)


@pytest.mark.parametrize("per", ["second", "metre"])
def test_bit_identical_to_the_composite_run_on_its_own_plan(per):
    """execute() on an open map with nothing to discover is the tracking phase alone: the run's own
    first plan, simulated here for its seed among others, gives its log exactly (with the process
    disturbance per second or per metre travelled). The plan's nominal carries the derated robot
    (headroom 0.8): the run saturates at the real robot's limits."""
    m = Map("open", (0.0, 0.0, 20.0, 10.0), obstacles=(box_polygon(10.0, 8.5, 4.0, 1.0),),
            start=Pose(2.0, 5.0, 0.0), goal=Pose(17.0, 5.0, 0.0))
    seed = 4
    r = execute(m, make_robot(make_model("unicycle"), footprint=default_footprint("unicycle")), m.start.as_array(), m.goal.as_array(),
                RunOptions(seed=seed, noise=NoiseOptions(process_per=per)))
    assert r.status in ("reached", "missed_goal") and len(r.plans) == 1
    assert ("process disturbance per metre travelled" in r.plans[0].verdict_line) == (per == "metre")
    o = r.options
    law = r.plans[0].law
    assert law.nominal.model.max_speed == 0.8 * r.model.max_speed
    res = simulate_shared(law, [11, seed, 3], o.noise, rate_hz=o.rate_hz, substeps=o.substeps, saturate=o.saturate,
                          model=r.model)
    _assert_trial_is(res, 1, "completed", r.log)
    assert np.any(res.u[1, :, 0] > law.nominal.model.max_speed)
    derated = simulate_shared(law, [seed], o.noise, rate_hz=o.rate_hz, substeps=o.substeps, saturate=o.saturate)
    assert derated.u[0, :, 0].max() == law.nominal.model.max_speed
    tracking = summary(r)["tracking"]
    assert res.rms_error_norm[1] == pytest.approx(tracking["rms_error_norm"], rel=1e-12)
    assert res.max_error_norm[1] == pytest.approx(tracking["max_error_norm"], rel=1e-12)


@pytest.mark.slow
def test_bit_identical_to_the_composite_run_of_a_car_with_a_trailer():
    """The car with a trailer reversing into the loading dock (nothing to discover): the vectorised
    trials reproduce the run's log exactly (the plant's generic RK4 step on the model's rhs, the
    hitch angles among the wrapped angle states). The run's plan tube is the linear one: a robot of
    several bodies' tube does not change its run (no cusp checks for it), so the log is the same with any
    tube kind, and the default sampled tube (2,097 rollouts of the rig, every body measured) takes most
    of the run's time."""
    from nhstab.maps import load_map
    from nhstab.robot import default_robot

    m = load_map("maps/trailer/loading_dock.yaml")
    robot = default_robot("car_trailer")
    seed = 3
    r = execute(m, robot, m.start.as_array(), m.goal.as_array(),
                RunOptions(seed=seed, tube=TubeOptions(kind="linear")))
    assert r.status in ("reached", "missed_goal") and len(r.plans) == 1, r.message
    o = r.options
    law = r.plans[0].law
    res = simulate_shared(law, [seed, 5], o.noise, rate_hz=o.rate_hz, substeps=o.substeps, saturate=o.saturate,
                          model=r.model)
    _assert_trial_is(res, 0, "completed", r.log)
    assert np.array_equal(res.e[0], robot.model.state_error(r.log["x"], r.log["x0"]))


def test_summaries_and_final_state_without_records_and_in_any_chunk(hilare):
    noise = NoiseOptions(scale=3.0)
    seeds = list(range(9))
    full = simulate_shared(hilare, seeds, noise)
    lean = simulate_shared(hilare, seeds, noise, record=False, chunk=4)
    assert lean.x is None and lean.y is None and lean.u is None and lean.e is None
    for key in ("rms_error_norm", "max_error_norm", "final_error_norm", "final_position_error", "x_final"):
        assert np.array_equal(getattr(full, key), getattr(lean, key)), key
    norms = np.linalg.norm(full.e, axis=2)
    assert np.allclose(full.rms_error_norm, np.sqrt(np.mean(norms[:, :-1] ** 2, axis=1)), rtol=1e-13)
    assert np.allclose(full.max_error_norm, norms[:, :-1].max(axis=1), rtol=1e-13)
    assert np.allclose(full.final_error_norm, norms[:, -1], rtol=1e-13)
    assert np.allclose(full.final_position_error, np.linalg.norm(full.e[:, -1, :2], axis=1), rtol=1e-13)
    assert np.array_equal(full.x_final, full.x[:, -1])


def test_results_do_not_depend_on_the_noise_block(hilare, monkeypatch):
    """The noise is drawn in blocks of samples (at least 64): blocks that end anywhere, including a
    last partial one and one at the end sample, give the same trials."""
    from nhstab.batch import vector

    noise = NoiseOptions(scale=2.0, impulses=((1.5, {"y": 0.3}),))
    ref = simulate_shared(hilare, [3, 4, 5], noise)
    for floats in (1, 9 * 112, 9 * 315, 9 * 1000):     # 3 trials x 3 states: blocks of 64, 112, 315, 316 samples
        monkeypatch.setattr(vector, "NOISE_BLOCK_FLOATS", floats)
        res = simulate_shared(hilare, [3, 4, 5], noise)
        for key in ("x", "y", "u", "e", "rms_error_norm", "x_final"):
            assert np.array_equal(getattr(res, key), getattr(ref, key)), (floats, key)


def _unchecked_noise(monkeypatch):
    """Noise levels beyond nhstab.limits.MAX_NOISE_LEVEL are refused before anything runs; the
    per-trial failure handling behind that bound is exercised with the check switched off."""
    monkeypatch.setattr(NoiseOptions, "validated", lambda self, state_names: self)


def test_on_states_sees_every_sample_of_every_chunk(hilare, monkeypatch):
    """The hook sees sample k = 0 .. S - 1 of each chunk in order: the true states the records hold
    (x at t_k) and the inputs applied from t_k (None at the end sample), read-only; with a failing
    trial, what its stack holds (the records show NaN from its lost sample on)."""
    _unchecked_noise(monkeypatch)
    noise = NoiseOptions(initial={"x": 1e308})
    draws = {s: np.random.default_rng(seed_for(s, "initial")).standard_normal(3)[0] for s in range(40)}
    bad = next(s for s, d in draws.items() if abs(d) > 1.9)
    good = [s for s, d in draws.items() if abs(d) < 1.0][:6]
    seeds = good[:2] + [bad] + good[2:]
    S = len(simulate_shared(hilare, [0], noise, record=False).t)
    xs, us, calls = np.full((7, S, 3), -1.0), np.full((7, S, 2), -1.0), []

    def on_states(rows, k, x, u):
        calls.append((rows.start, rows.stop, k))
        assert x.shape == (rows.stop - rows.start, 3) and not x.flags.writeable
        xs[rows, k] = x
        if k < S - 1:
            assert u.shape == (rows.stop - rows.start, 2) and not u.flags.writeable
            us[rows, k] = u
        else:
            assert u is None

    with np.errstate(over="ignore", invalid="ignore"):
        res = simulate_shared(hilare, seeds, noise, chunk=3, on_states=on_states)
        lean = simulate_shared(hilare, seeds, noise, chunk=3, record=False, on_states=lambda *a: None)
    assert calls == [(lo, min(lo + 3, 7), k) for lo in (0, 3, 6) for k in range(S)]
    assert list(res.status) == ["completed"] * 2 + ["numerical_failure"] + ["completed"] * 4
    ok = np.array([0, 1, 3, 4, 5, 6])
    assert np.array_equal(xs[ok], res.x[ok]) and np.array_equal(us[ok, :-1], res.u[ok, :-1])
    lost = int(np.flatnonzero(res.t == res.t_fail[2])[0])
    assert np.array_equal(xs[2, :lost], res.x[2, :lost]) and np.isnan(res.x[2, lost:]).all()
    assert not (xs[2] == -1.0).any()            # seen at every sample, lost or not
    for key in ("rms_error_norm", "max_error_norm", "final_error_norm", "x_final", "status"):
        assert np.array_equal(getattr(lean, key), getattr(res, key), equal_nan=key != "status"), key


def test_on_states_must_be_callable(hilare):
    with pytest.raises(InputError) as err:
        simulate_shared(hilare, [0], NoiseOptions(), on_states="x")
    assert err.value.argument == "on_states"


def test_t_end_stops_early_on_the_same_samples(hilare):
    full = simulate_shared(hilare, [5, 6], NoiseOptions())
    part = simulate_shared(hilare, [5, 6], NoiseOptions(), t_end=1.0)
    assert part.t[-1] == 50 * 0.02 and len(part.t) == 51
    assert np.array_equal(part.x, full.x[:, :51]) and np.array_equal(part.u[:, :50], full.u[:, :50])
    assert np.array_equal(part.y[:, :50], full.y[:, :50])


# ---- behaviour -----------------------------------------------------------------------------------------

def test_without_noise_the_trials_follow_the_nominal_to_integration_accuracy():
    """No initial error, no noise: the error is the discretisation alone. On a nominal with a
    constant input (the Hilare circle) the held mean input is exact and the error is integration
    error; on the sinusoid the zero-order hold of a varying input leaves O(T^2) that the feedback
    keeps small."""
    t = np.linspace(0.0, 2 * math.pi, 315)
    circle = Nominal.from_inputs(make_model("unicycle"), lambda s: np.ones((len(s), 2)), np.zeros(3), t)
    res = simulate_shared(_law(circle), [0, 1], NoiseOptions(scale=0.0))
    assert np.all(res.max_error_norm < 1e-6) and np.array_equal(res.x[0], res.x[1])
    res = simulate_shared(_law(hilare_sinusoid(315)), [0], NoiseOptions(scale=0.0))
    assert res.max_error_norm[0] < 1e-4


def test_measurements_have_the_configured_spread(hilare):
    res = simulate_shared(hilare, list(range(300)), NoiseOptions(sensor={"x": 0.05, "y": 0.01, "theta": 0.02}))
    rms = np.sqrt(np.mean((res.y - res.x) ** 2, axis=(0, 1)))
    # 300 x 316 draws per state: a relative standard error of 0.2 %
    assert np.allclose(rms, [0.05, 0.01, 0.02], rtol=0.01)


def test_a_trial_that_blows_up_leaves_the_others_alone(hilare, monkeypatch):
    """An initial-error level of 1e308 overflows the trials whose draw exceeds 1.79 in size: they
    fail ("numerical_failure", frozen, NaN from the lost sample on) exactly when the loop does;
    the others are bit-identical to a batch without them."""
    _unchecked_noise(monkeypatch)
    noise = NoiseOptions(initial={"x": 1e308})
    draws = {s: np.random.default_rng(seed_for(s, "initial")).standard_normal(3)[0] for s in range(40)}
    bad = next(s for s, d in draws.items() if abs(d) > 1.9)
    good = [s for s, d in draws.items() if abs(d) < 1e-2][:1] + [0]
    mixed = simulate_shared(hilare, [good[0], bad, good[1]], noise)
    alone = simulate_shared(hilare, good, noise)
    assert list(mixed.status) == ["completed", "numerical_failure", "completed"]
    for key in ("x", "y", "u", "e", "rms_error_norm", "final_error_norm", "x_final"):
        assert np.array_equal(getattr(mixed, key)[[0, 2]], getattr(alone, key)), key
    with np.errstate(over="ignore", invalid="ignore"):
        status, log = reference_loop(hilare, bad, noise)
    _assert_trial_is(mixed, 1, status, log)
    assert mixed.t_fail[1] == mixed.t[len(log["t"])] and np.isnan(mixed.t_fail[[0, 2]]).all()
    assert np.isnan(mixed.final_error_norm[1]) and np.isnan(mixed.x_final[1]).all()


def test_saturation_clips_the_inputs(hilare):
    noise = NoiseOptions(initial={"x": 1.5, "y": 1.5, "theta": 1.0})
    lim = make_model("unicycle").input_limits()
    clipped = simulate_shared(hilare, list(range(20)), noise)
    free = simulate_shared(hilare, list(range(20)), noise, saturate=False)
    u = clipped.u[:, :-1]
    assert np.all((u >= lim[:, 0]) & (u <= lim[:, 1]))
    assert np.any(u == lim[:, 1]) and np.any(u == lim[:, 0])
    assert np.any(np.abs(free.u[:, :-1]) > lim[:, 1])


@pytest.mark.parametrize("kwargs, argument", [
    ({"seeds": []}, "seeds"), ({"seeds": [1, -2]}, "seeds"), ({"seeds": [1.5]}, "seeds"), ({"seeds": "12"}, "seeds"),
    ({"rate_hz": 0.0}, "rate_hz"), ({"substeps": 2.5}, "substeps"), ({"chunk": 0}, "chunk"),
    ({"t_end": 100.0}, "t_end"), ({"t_end": -1.0}, "t_end"), ({"saturate": 1}, "saturate"),
    ({"record": "no"}, "record"), ({"noise": NoiseOptions(sensor={"phi": 0.1})}, "noise.sensor.phi"),
    ({"noise": {"scale": 1.0}}, "noise"), ({"law": None}, "law"), ({"model": make_model("rwd_car")}, "model"),
])
def test_bad_arguments_name_the_argument(hilare, kwargs, argument):
    args = {"law": hilare, "seeds": [0], "noise": NoiseOptions(), **kwargs}
    with pytest.raises(InputError) as err:
        simulate_shared(args.pop("law"), args.pop("seeds"), args.pop("noise"), **args)
    assert err.value.argument == argument


# ---- a process disturbance per metre travelled -------------------------------------------------------

def _open_loop(speed: float, duration: float = 2.0):
    """The unicycle driving straight along x at ``speed`` (0: standing) under the open-loop law."""
    t = np.linspace(0.0, duration, 101)
    nominal = Nominal.from_inputs(make_model("unicycle"), lambda s: np.tile([speed, 0.0], (len(s), 1)), np.zeros(3), t)
    return build_law(nominal, ControllerOptions(kind="open-loop"), {})


_QUIET = {"initial": {"x": 0.0, "y": 0.0, "theta": 0.0}, "sensor": {"x": 0.0, "y": 0.0, "theta": 0.0}}


def test_a_disturbance_per_metre_leaves_a_standing_robot_where_it_stands():
    """A robot at rest (u = 0, no initial error or sensor noise) under the default process intensities:
    per metre travelled nothing moves it, at every sample, exactly; per second the same seeds spread it
    as sigma sqrt(t) (the closed form of a Wiener process, within 4.5 standard errors of 2,000 trials)."""
    law = _open_loop(0.0)
    seeds = list(range(2000))
    still = simulate_shared(law, seeds, NoiseOptions(process_per="metre", **_QUIET))
    assert np.all(still.x == 0.0)
    drift = simulate_shared(law, seeds, NoiseOptions(**_QUIET))
    t_end = drift.t[-1]
    sigma = NoiseOptions().vector("process", ("x", "y", "theta")) * math.sqrt(t_end)
    observed = drift.x[:, -1].std(axis=0)
    assert np.all(np.abs(observed / sigma - 1.0) < 4.5 / math.sqrt(2 * len(seeds))), observed / sigma


@pytest.mark.parametrize("per, speed", [("metre", 0.5), ("metre", 0.9), ("second", 0.5)])
def test_a_disturbance_per_metre_grows_with_the_distance_travelled(per, speed):
    """Driving straight at ``speed`` with a lateral disturbance only (sigma = 0.05 on y), open loop: the
    final y is the sum of the increments, N(0, sigma^2 d) per metre (d = speed x duration) and
    N(0, sigma^2 t) per second. The sample variance of 4,000 trials is within 4.5 standard errors
    (relative SE sqrt(2 / 4000)); the two forms differ by a factor 1 / speed, far beyond that. The
    linear tube predicts the same closed form to rounding."""
    law = _open_loop(speed)
    noise = NoiseOptions(process_per=per, process={"x": 0.0, "y": 0.05, "theta": 0.0}, **_QUIET)
    res = simulate_shared(law, list(range(4000)), noise)
    t_end = res.t[-1]
    expected = 0.05 ** 2 * (speed * t_end if per == "metre" else t_end)
    var = res.x[:, -1, 1].var()
    assert abs(var / expected - 1.0) < 4.5 * math.sqrt(2 / 4000), (var, expected)
    assert np.all(res.x[:, :, 2] == 0.0)          # the heading is not disturbed: the moves stay along x
    from nhstab.geometry import Footprint
    from nhstab.tubes import predict_tube

    tube = predict_tube(law, noise, Footprint.disc(0.3), None, kind="linear")
    assert tube.std[-1, 1] ** 2 == pytest.approx(expected, rel=1e-9)
