"""Nominal trajectories and their files."""

import numpy as np
import pytest
from nhstab.errors import InputError, TrajectoryError
from nhstab.models import make_model
from nhstab.nominal import Nominal
from nhstab.trajectory_io import column_names, read_trajectory, write_trajectory
from nominals import hilare_sinusoid


def test_integrated_nominal_is_feasible():
    nom = hilare_sinusoid(2 * np.pi, hz=100)
    assert nom.feasibility_residual() < 1e-9


def test_feasibility_residual_of_a_known_deviation():
    """x0 = the exact Hilare sinusoid plus a bump in y that starts at 0: the integration from x0(0)
    under u0 is the exact trajectory, so the residual is the bump's largest value at the grid points."""
    exact = hilare_sinusoid(2 * np.pi, hz=50)

    def x_func(t):
        x = exact.at(t)[0].copy()
        x[..., 1] += 1e-4 * np.sin(0.5 * np.asarray(t)) ** 2
        return x

    nom = Nominal.from_functions(make_model("unicycle"), x_func, lambda t: exact.at(t)[1], exact.t)
    bump = 1e-4 * np.sin(0.5 * exact.t) ** 2
    assert nom.feasibility_residual() == pytest.approx(bump.max(), rel=1e-6)


#: the turn rate jumps from 0 to 1 rad/s at this time, inside a grid interval of the tests below
JUMP_AT = 1.2345


def _jump_functions(ts: float = JUMP_AT):
    """(x_func, u_func): a unicycle at 1 m/s whose turn rate jumps from 0 to 1 rad/s at ts, and its
    exact solution (a straight line, then an arc)."""
    def u_func(t):
        t = np.asarray(t, dtype=float)
        return np.stack([np.ones_like(t), (t >= ts).astype(float)], -1)

    def x_func(t):
        t = np.asarray(t, dtype=float)
        tau = np.maximum(t - ts, 0.0)
        return np.stack([np.minimum(t, ts) + np.sin(tau), 1.0 - np.cos(tau), tau], -1)
    return x_func, u_func


def test_feasibility_residual_refines_where_the_input_jumps():
    """The turn rate jumps from 0 to 1 rad/s at t = 1.2345 s, inside a grid interval; x0 is the exact
    solution (a straight line, then an arc). One fixed DOP853 step per interval would be off by about
    1e-3 there; the refinement brings the residual to the integrator's tolerance."""
    model = make_model("unicycle")
    x_func, u_func = _jump_functions()
    nom = Nominal.from_functions(model, x_func, u_func, np.linspace(0.0, 4.0, 201))
    assert nom.feasibility_residual() < 1e-9
    late = Nominal.from_functions(model, lambda t: x_func(np.asarray(t) - 0.01), u_func, np.linspace(0.0, 4.0, 201))
    assert late.feasibility_residual() > 1e-3            # a genuinely infeasible x0 is reported


def test_known_breaks_cut_the_intervals_and_wrong_ones_change_nothing(monkeypatch):
    """The same jump with its time given (``u_breaks``): the interval is cut there and one level of
    steps suffices (no refinement); breaks at the wrong times (or none) leave the answer to the
    refinement, and an infeasible x0 is still reported."""
    import nhstab.nominal as nominal_module

    model = make_model("unicycle")
    ts = JUMP_AT
    x_func, u_func = _jump_functions()
    levels = []
    step = nominal_module._Shooting.interval
    monkeypatch.setattr(nominal_module._Shooting, "interval",
                        lambda self, *a, **k: levels.append(len(a[0])) or step(self, *a, **k))
    grid = np.linspace(0.0, 4.0, 201)
    for breaks, most in (([ts], 1), ([0.5, 2.0001, ts + 1e-3], None), (None, None)):
        # the jump's own time, three wrong ones, none
        nom = Nominal.from_functions(model, x_func, u_func, grid)
        nom.u_breaks = None if breaks is None else np.array(breaks)
        levels.clear()
        assert nom.feasibility_residual() < 1e-9
        if most is not None:
            assert len(levels) == most and levels[0] == 201          # 200 intervals, one of them cut
        else:
            assert len(levels) > 1                                   # the refinement found the jump
        late = Nominal.from_functions(model, lambda t: x_func(np.asarray(t) - 0.01), u_func, grid)
        late.u_breaks = nom.u_breaks
        assert late.feasibility_residual() > 1e-3


def test_sampled_nominal_interpolates_between_samples():
    """Cubic Hermite with the model's slopes: 4th order, so a 100 Hz circle is exact to ~1e-9."""
    model = make_model("unicycle")
    t = np.linspace(0, 6, 601)
    x = np.stack([np.sin(t), 1 - np.cos(t), t], -1)
    nom = Nominal.from_samples(model, t, x, np.ones((601, 2)))
    tau = np.linspace(0, 6, 1777)
    x_mid, u_mid = nom.at(tau)
    np.testing.assert_allclose(x_mid, np.stack([np.sin(tau), 1 - np.cos(tau), tau], -1), atol=1e-9)
    np.testing.assert_allclose(u_mid, 1.0)


def test_wrapped_angles_are_unwrapped():
    model = make_model("unicycle")
    t = np.linspace(0, 10, 101)
    theta = np.mod(t, 2 * np.pi) - np.pi
    nom = Nominal.from_samples(model, t, np.stack([0 * t, 0 * t, theta], -1), np.stack([0 * t, 1 + 0 * t], -1))
    assert np.all(np.diff(nom.x[:, 2]) > 0)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_round_trip(tmp_path, suffix):
    nom = hilare_sinusoid(2 * np.pi, hz=20)
    path = write_trajectory(tmp_path / f"traj{suffix}", nom)
    back = read_trajectory(path, nom.model)
    np.testing.assert_array_equal(back.t, nom.t)
    np.testing.assert_array_equal(back.x, nom.x)
    np.testing.assert_array_equal(back.u, nom.u)
    if suffix == ".csv":
        assert path.read_text().splitlines()[0] == ",".join(column_names(nom.model))
        assert column_names(nom.model) == ["t [s]", "x [m]", "y [m]", "theta [rad]", "v [m/s]", "omega [rad/s]"]


def test_bad_files(tmp_path):
    model = make_model("unicycle")
    with pytest.raises(InputError, match="existing"):
        read_trajectory(tmp_path / "missing.csv", model)
    p = tmp_path / "bad.csv"
    for text, match in (("t,x,y,theta,v\n0,0,0,0,1\n1,1,0,0,1\n", "missing omega"),
                        ("t,x,y,theta,v,omega,extra\n0,0,0,0,1,0,0\n1,1,0,0,1,0,0\n", "unknown extra"),
                        ("t,x,y,theta,v,omega\n0,0,0,0,1,0\n1,nan,0,0,1,0\n", "'x' must be finite"),
                        ("t,x,y,theta,v,omega\n0,0,0,0,1,0\n1,oops,0,0,1,0\n", "numbers")):
        p.write_text(text)
        with pytest.raises(TrajectoryError, match=match):
            read_trajectory(p, model)
    q = tmp_path / "bad.npz"
    np.savez(q, t=np.arange(5.0), x=np.zeros((5, 4)), u=np.zeros((5, 2)))
    with pytest.raises(TrajectoryError, match="'x' must be shape \\(5, 3\\)"):
        read_trajectory(q, model)
    r = tmp_path / "junk.npz"
    r.write_bytes(b"not a zip")
    with pytest.raises(InputError, match="readable NPZ"):
        read_trajectory(r, model)
