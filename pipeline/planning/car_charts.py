"""The two kinematic cars in chained form, and steering a car with the chained-form sinusoids of
:mod:`nhstab.planning.steering`.

Cars in chained form (valid for |theta| < pi/2 and |phi| < pi/2)
---------------------------------------------------------------
Both cars move their rear-axle midpoint with body speed s along the heading and turn with
theta' = tan(phi) s / L: the rear-wheel-drive car has s = v, the front-wheel-drive car of eq. (12)
has s = cos(phi) u1 (x' = cos(phi) cos(theta) u1 = cos(theta) s, theta' = sin(phi) u1 / L =
tan(phi) s / L). Hence the same chained coordinates serve both:
    z1 = x,  z2 = tan(phi) / (L cos^3 theta),  z3 = tan(theta),  z4 = y,
    v1 = cos(theta) s,  v2 = z2'.
Check: z1' = cos(theta) s = v1; z4' = sin(theta) s = tan(theta) v1 = z3 v1;
z3' = theta' / cos^2 theta = tan(phi) s / (L cos^2 theta) = z2 v1.
Differentiating z2:
    z2' = phi' / (L cos^2 phi cos^3 theta) + 3 tan(phi) sin(theta) theta' / (L cos^4 theta)
        = omega_s / (L cos^2 phi cos^3 theta) + 3 z2^2 z3 v1 / (1 + z3^2)
(using tan(phi) = L z2 cos^3 theta and s = v1 / cos theta), so the model inputs are
    s = v1 / cos(theta) = v1 sqrt(1 + z3^2),
    omega_s = L cos^2(phi) cos^3(theta) (v2 - 3 z2^2 z3 v1 / (1 + z3^2)),
with v = s (rwd_car) or u1 = s / cos(phi) (fwd_car), and the inverse state map
theta = arctan z3, phi = arctan(L z2 cos^3 theta).

Local frames. The chart is singular at theta = +-pi/2, so :func:`steer_car` expresses both poses
in a frame (origin, heading alpha), steers there, checks that |theta - alpha| stays below
``theta_limit`` (default 1.2 rad) along the whole steered path, and maps the path back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import InputError, require_finite, require_positive
from ..geometry import wrap_angle
from ..models import MODELS
from ..models.base import SteeredCar
from .steering import STEERING_MODES, SteeringPlan, _array, _count, _vector, steer_chained, steer_chained_constant_v1

__all__ = ["CarSteering", "to_chained", "from_chained", "car_inputs_from_chained", "chained_inputs_from_car", "steer_car"]


# ---------------------------------------------------------------------------------------------
# cars <-> chained form
# ---------------------------------------------------------------------------------------------
#: the models with a chained-form chart: the steered cars (x, y, theta, phi in their own state order)
CAR_MODELS = tuple(name for name, cls in MODELS.items() if issubclass(cls, SteeredCar))


@dataclass(frozen=True)
class _CarLayout:
    """Where a steered car keeps its heading and steering angle in its state (from its state names),
    and whether its speed input drives the front wheels (the body's speed is then cos(phi) times it)."""

    name: str
    theta: int
    phi: int
    front_wheel_drive: bool


def _car_kind(model) -> tuple[_CarLayout, float]:
    if not isinstance(model, SteeredCar):
        name = getattr(model, "name", None)
        raise InputError("model", "a " + " or ".join(CAR_MODELS) + " model", name if name is not None else model)
    L = require_positive(f"{model.name}.wheelbase", getattr(model, "wheelbase", None))
    names = model.state_names
    return _CarLayout(model.name, names.index("theta"), names.index("phi"), model.front_wheel_drive), L


def _theta_phi(lay: _CarLayout, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return x[..., lay.theta], x[..., lay.phi]


def to_chained(model, x) -> np.ndarray:
    """Model state(s) (..., 4) in model order to chained coordinates (..., 4):
    z = (x, tan(phi) / (L cos^3 theta), tan(theta), y). Needs |theta| < pi/2, |phi| < pi/2."""
    lay, L = _car_kind(model)
    x = _array("x", x, last=4)
    th, phi = _theta_phi(lay, x)
    if np.any(np.abs(th) >= 0.5 * np.pi):
        raise InputError("x", "heading |theta| < pi/2 (the chained chart)", f"max |theta| {np.abs(th).max():.6g}")
    if np.any(np.abs(phi) >= 0.5 * np.pi):
        raise InputError("x", "steering angle |phi| < pi/2", f"max |phi| {np.abs(phi).max():.6g}")
    ct = np.cos(th)
    z = np.empty(x.shape)
    z[..., 0] = x[..., 0]
    z[..., 1] = np.tan(phi) / (L * ct**3)
    z[..., 2] = np.tan(th)
    z[..., 3] = x[..., 1]
    return z


def from_chained(model, z) -> np.ndarray:
    """Chained coordinates (..., 4) to model state(s) in model order:
    theta = arctan z3, phi = arctan(L z2 cos^3 theta) (inverse of :func:`to_chained`)."""
    lay, L = _car_kind(model)
    z = _array("z", z, last=4)
    th = np.arctan(z[..., 2])
    phi = np.arctan(L * z[..., 1] * np.cos(th) ** 3)
    x = np.empty(z.shape)
    x[..., 0] = z[..., 0]
    x[..., 1] = z[..., 3]
    x[..., lay.theta], x[..., lay.phi] = th, phi
    return x


def car_inputs_from_chained(model, z, v) -> np.ndarray:
    """Model inputs (..., 2) that realise chained inputs v = (v1, v2) at chained state z.

    Body speed s = v1 sqrt(1 + z3^2) (= v1 / cos theta);
    omega_s = L cos^2(phi) cos^3(theta) (v2 - 3 z2^2 z3 v1 / (1 + z3^2));
    first input v = s (rwd_car) or u1 = s / cos(phi) (fwd_car, whose body speed is cos(phi) u1).
    """
    lay, L = _car_kind(model)
    return _car_inputs(lay, L, _array("z", z, last=4), _array("v", v, last=2))


def _car_inputs(lay: _CarLayout, L: float, z: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`car_inputs_from_chained` without validation; uses only z2 and z3 of ``z``."""
    z2, z3 = z[..., 1], z[..., 2]
    v1, v2 = v[..., 0], v[..., 1]
    q = 1.0 + z3 * z3
    ct = 1.0 / np.sqrt(q)                        # cos theta (theta in (-pi/2, pi/2))
    cphi2 = 1.0 / (1.0 + (L * z2 * ct**3) ** 2)  # cos^2 phi
    s = v1 * np.sqrt(q)
    omega = L * cphi2 * ct**3 * (v2 - 3.0 * z2 * z2 * z3 * v1 / q)
    first = s / np.sqrt(cphi2) if lay.front_wheel_drive else s
    return np.stack(np.broadcast_arrays(first, omega), axis=-1)


def chained_inputs_from_car(model, x, u) -> np.ndarray:
    """Inverse input map: model state x and inputs u (model order) to chained inputs (v1, v2).

    v1 = cos(theta) s with s = v (rwd) or cos(phi) u1 (fwd);
    v2 = omega_s / (L cos^2 phi cos^3 theta) + 3 z2^2 z3 v1 / (1 + z3^2).
    """
    lay, L = _car_kind(model)
    z = to_chained(model, x)
    x = np.asarray(x, dtype=float)
    u = _array("u", u, last=2)
    th, phi = _theta_phi(lay, x)
    s = np.cos(phi) * u[..., 0] if lay.front_wheel_drive else u[..., 0]
    v1 = np.cos(th) * s
    z2, z3 = z[..., 1], z[..., 2]
    v2 = u[..., 1] / (L * np.cos(phi) ** 2 * np.cos(th) ** 3) + 3.0 * z2 * z2 * z3 * v1 / (1.0 + z3 * z3)
    return np.stack(np.broadcast_arrays(v1, v2), axis=-1)


# ---------------------------------------------------------------------------------------------
# car steering in a local frame
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CarSteering:
    """Result of :func:`steer_car`.

    ``t`` (N,), model states ``x`` (N, 4) and inputs ``u`` (N, 2) in model order on the grid
    (``points_per_phase`` per phase + the end point; inputs right-continuous at phase boundaries);
    maxima over the grid; ``final_error`` = model.state_error(x(T), xf) (angles wrapped);
    ``frame`` = {"name", "origin", "heading"} of the chart; ``max_abs_local_theta`` the largest
    |theta - heading| along the path; ``plan`` the chained plan in the local frame. ``states_at`` /
    ``inputs_at`` evaluate the exact trajectory at any t in [0, T].
    """

    model: object
    x0: np.ndarray
    xf: np.ndarray
    T: float
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    phase_times: np.ndarray
    max_abs_phi: float
    max_abs_omega_s: float
    max_speed: float
    max_abs_local_theta: float
    final_error: np.ndarray
    frame: dict
    plan: SteeringPlan
    within_limits: dict = field(default_factory=dict)
    _to_world: Callable = field(default=None, repr=False)

    @property
    def final_error_norm(self) -> float:
        return float(np.linalg.norm(self.final_error))

    def states_at(self, t) -> np.ndarray:
        """Model states (model order, world frame) at times t, shape t.shape + (4,)."""
        return self._to_world(from_chained(self.model, self.plan.states(t)))

    def inputs_at(self, t) -> np.ndarray:
        """Model inputs at times t, shape t.shape + (2,) (frame-independent)."""
        lay, L = _car_kind(self.model)
        return _car_inputs(lay, L, self.plan.states(t), self.plan.inputs(t))


def _pose_parts(lay: _CarLayout, x: np.ndarray):
    th, phi = _theta_phi(lay, x)
    return x[..., 0], x[..., 1], th, phi


def _assemble(lay: _CarLayout, px, py, th, phi) -> np.ndarray:
    cols = [px, py, None, None]
    cols[lay.theta], cols[lay.phi] = th, phi
    return np.stack(np.broadcast_arrays(*cols), axis=-1)


def _frames(frame, x0, xf, lay):
    _, _, th0, _ = _pose_parts(lay, x0)
    _, _, thf, _ = _pose_parts(lay, xf)
    origin = np.array([x0[0], x0[1]])
    mean = float(th0 + 0.5 * wrap_angle(thf - th0))
    options = {"mean": mean, "start": float(th0), "goal": float(thf)}
    if isinstance(frame, str):
        if frame == "auto":
            return [(key, origin, val) for key, val in options.items()]
        if frame in options:
            return [(frame, origin, options[frame])]
        if frame == "world":
            return [("world", np.zeros(2), 0.0)]
        raise InputError("frame", "'auto', 'mean', 'start', 'goal', 'world' or a heading in radians", frame)
    return [("heading", origin, require_finite("frame", frame))]


def steer_car(model, x0, xf, T: float | None = None, frame="auto", *, mode: str = "phased",
              points_per_phase: int = 200, theta_limit: float = 1.2, amplitude="balanced",
              balance: float | None = None, phase_fractions=None, check_limits: bool = False) -> CarSteering:
    """Exactly steer a ``rwd_car`` or ``fwd_car`` from model state x0 to xf through the chained form.

    The poses are expressed in a local frame (origin = x0's position, heading alpha): ``frame``
    "mean" (alpha = mean of the two headings), "start", "goal", "world" (alpha = 0, world origin), a
    number (alpha itself), or "auto" (try mean, start and goal; keep the frame whose steered path
    has the smallest max |theta - alpha|). In the frame the chained plan (``mode``) is computed and
    mapped back (the heading is offset so x(0) = x0 exactly; xf's heading is met modulo 2 pi).
    Refuses with :class:`InputError` if |theta - alpha| reaches ``theta_limit`` (rad, < pi/2)
    anywhere on the grid of the best frame (detail gives max |theta - alpha| and max |phi|).

    ``T``: total time; ``None`` picks the shortest T at which max |speed| and max |omega_s| meet
    the model's limits (inputs scale as 1/T along the same geometric path). ``check_limits``:
    raise InputError if the steering angle, speed or steering rate limit is exceeded.
    ``mode``: "phased" (:func:`steer_chained`, the car drives back and forth in its sinusoidal
    phases) or "constant_v1" (:func:`steer_chained_constant_v1`: v1 = cos(theta) s keeps one sign, so
    the car never reverses within the piece; refused with InputError on ``xf`` when the goal does not
    advance along the frame's axis). ``amplitude``/``balance``/``phase_fractions`` go to
    :func:`steer_chained` (phased mode only); ``balance`` defaults to L^2, i.e. |a| = |b| in the
    dimensionless chained coordinates (x/L, tan(phi)/cos^3 theta, tan theta, y/L).
    """
    lay, L = _car_kind(model)
    if mode not in STEERING_MODES:
        raise InputError("mode", "one of " + ", ".join(STEERING_MODES), mode)
    if mode == "constant_v1":
        for key, value in (("amplitude", None if amplitude == "balanced" else amplitude), ("balance", balance),
                           ("phase_fractions", phase_fractions)):
            if value is not None:
                raise InputError(key, "left at its default: it applies to mode 'phased' only", value)
    x0 = _vector("x0", x0, (4,))
    xf = _vector("xf", xf, (4,))
    if T is not None:
        T = require_positive("T", T)
    ppp = _count("points_per_phase", points_per_phase)
    theta_limit = require_positive("theta_limit", theta_limit)
    balance = L * L if balance is None else require_positive("balance", balance)
    if theta_limit >= 0.5 * np.pi:
        raise InputError("theta_limit", "below pi/2 rad", theta_limit)
    for label, xx in (("x0", x0), ("xf", xf)):
        if abs(_theta_phi(lay, xx)[1]) >= 0.5 * np.pi:
            raise InputError(label, "a steering angle |phi| < pi/2", xx)

    def chained(z0, zf, T):
        if mode == "constant_v1":
            return steer_chained_constant_v1(z0, zf, T)
        return steer_chained(z0, zf, T, amplitude=amplitude, balance=balance, phase_fractions=phase_fractions)

    best = None
    refusals = []
    tried = []
    for fname, origin, alpha in _frames(frame, x0, xf, lay):
        if any(alpha == a and np.array_equal(origin, o) for o, a in tried):
            continue        # the same chart as an earlier frame (e.g. a straight piece): same plan
        tried.append((origin, alpha))
        ca, sa = math.cos(alpha), math.sin(alpha)

        def to_local(x, origin=origin, ca=ca, sa=sa, alpha=alpha):
            px, py, th, phi = _pose_parts(lay, x)
            dx, dy = px - origin[0], py - origin[1]
            return _assemble(lay, ca * dx + sa * dy, -sa * dx + ca * dy, wrap_angle(th - alpha), phi)

        l0, lf = to_local(x0), to_local(xf)
        ends = max(abs(_theta_phi(lay, l0)[0]), abs(_theta_phi(lay, lf)[0]))
        if ends >= theta_limit:
            refusals.append(f"{fname}: endpoint |theta - alpha| = {ends:.3f}")
            continue
        z0l, zfl = to_chained(model, l0), to_chained(model, lf)
        if mode == "constant_v1" and zfl[0] == z0l[0]:
            refusals.append(f"{fname}: the goal does not advance along the frame's axis (v1 would be 0)")
            continue
        plan = chained(z0l, zfl, 1.0 if T is None else T)
        dense = plan.grid(max(ppp, 2000) if T is None else ppp)
        zl = plan.states(dense, coords=3)          # z4 (= y) plays no part in the chart or the inputs
        th_local = np.arctan(zl[:, 2])
        max_th = float(np.abs(th_local).max())
        if max_th >= theta_limit:
            phi_max = float(np.abs(np.arctan(L * zl[:, 1] * np.cos(th_local) ** 3)).max())
            refusals.append(f"{fname}: max |theta - alpha| = {max_th:.3f} along the path, max |phi| = {phi_max:.3f}")
            continue
        if best is None or max_th < best[0]:
            best = (max_th, fname, origin, alpha, plan, l0, dense, zl)
    if best is None:
        raise InputError("xf", f"a goal reachable within the chained chart (|theta - alpha| < {theta_limit:g} rad)",
                         xf, detail="; ".join(refusals) or "no frame")
    max_th, fname, origin, alpha, plan, l0, dense, zl = best

    if T is None:   # time scaling: same path, inputs divided by T
        uu = _car_inputs(lay, L, zl, plan.inputs(dense))
        T = max(float(np.abs(uu[:, 0]).max()) / model.max_speed,
                float(np.abs(uu[:, 1]).max()) / model.max_steer_rate) * 1.001
        if T <= 0.0:
            T = 1.0   # x0 == xf: nothing to do
        plan = chained(plan.z0, plan.zf, T)

    th_l0 = float(_theta_phi(lay, l0)[0])
    th0 = float(_theta_phi(lay, x0)[0])
    ca, sa = math.cos(alpha), math.sin(alpha)

    def to_world(xl):
        px, py, th, phi = _pose_parts(lay, xl)
        return _assemble(lay, origin[0] + ca * px - sa * py, origin[1] + sa * px + ca * py,
                         th0 + (th - th_l0), phi)

    t = plan.grid(ppp)
    z = plan.states(t)
    u = car_inputs_from_chained(model, z, plan.inputs(t))
    x = to_world(from_chained(model, z))
    x[0] = x0       # exact start (differs by round-off only)
    phi = _theta_phi(lay, x)[1]
    res_max_phi = float(np.abs(phi).max())
    res_max_speed = float(np.abs(u[:, 0]).max())
    res_max_omega = float(np.abs(u[:, 1]).max())
    within = {"steer": res_max_phi <= model.max_steer, "speed": res_max_speed <= model.max_speed,
              "steer_rate": res_max_omega <= model.max_steer_rate}
    if check_limits and not all(within.values()):
        raise InputError("xf", "reachable within the model's limits",
                         xf, detail=f"max |phi| {res_max_phi:.3f} (limit {model.max_steer:g}), max speed "
                         f"{res_max_speed:.3f} (limit {model.max_speed:g}), max |omega_s| {res_max_omega:.3f} "
                         f"(limit {model.max_steer_rate:g})")
    return CarSteering(
        model=model, x0=x0, xf=xf, T=float(T), t=t, x=x, u=u, phase_times=plan.phase_times.copy(),
        max_abs_phi=res_max_phi, max_abs_omega_s=res_max_omega, max_speed=res_max_speed,
        max_abs_local_theta=float(np.abs(np.arctan(z[:, 2])).max()),
        final_error=model.state_error(x[-1], xf),
        frame={"name": fname, "origin": origin.copy(), "heading": float(alpha)},
        plan=plan, within_limits=within, _to_world=to_world)
