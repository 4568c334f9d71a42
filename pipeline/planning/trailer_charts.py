"""The car with one trailer in chained form, and steering it with the chained-form sinusoids and
polynomials of :mod:`nhstab.planning.steering`.

Chained form of the car with one trailer (Sordalen 1993; Tilbury, Laumond, Murray, Sastry, Walsh 1992)
-------------------------------------------------------------------------------------------------
State (x, y, theta, phi, theta1) of ``car_trailer`` with N = 1 (car wheelbase L, hitch length d);
D = theta - theta1 is the hitch angle. The trailer's axle point (x1, y1) = (x - d cos theta1,
y - d sin theta1) is a flat output: it moves along the trailer's heading with the trailer's axle speed
v_1 = v cos D, and the trailer turns with theta1' = v sin D / d = v_1 tan(D) / d, i.e. the trailer is
a car of wheelbase d "steered" by D. Take it as z1 = x1, z5 = y1 and the derivatives of y1 with
respect to x1 as the other coordinates (the construction of Sordalen for n trailers, here for one):

    z1 = x1 = x - d cos theta1,                      z5 = y1 = y - d sin theta1,
    z4 = dy1/dx1 = tan theta1,
    z3 = dz4/dx1 = tan(D) / (d cos^3 theta1),
    z2 = dz3/dx1 = (tan(phi)/L - sin(D)/d) / (d cos^3(D) cos^4(theta1)) + 3 tan^2(D) sin(theta1) / (d^2 cos^5 theta1),
    v1 = x1' = v cos(D) cos(theta1),                 v2 = z2'.

Check, with v = v1 / (cos D cos theta1): z5' = v_1 sin theta1 = tan(theta1) v1 = z4 v1;
z4' = theta1' / cos^2 theta1 = v sin(D) / (d cos^2 theta1) = z3 v1;
z3' = (dz3/dD) D' + (dz3/dtheta1) theta1' with dz3/dD = 1 / (d cos^2 D cos^3 theta1),
dz3/dtheta1 = 3 tan(D) sin(theta1) / (d cos^4 theta1), D' = v (tan(phi)/L - sin(D)/d) and
theta1' = v sin(D) / d, which gives z3' = z2 v1 with z2 as above. Writing z2 = F(phi, D, theta1) =
(tan(phi)/L - sin(D)/d) G + H, G = 1 / (d cos^3 D cos^4 theta1), H = 3 tan^2(D) sin(theta1) / (d^2 cos^5 theta1):
    F_phi = G / (L cos^2 phi),
    F_D = -cos(D) G / d + 3 tan(D) (tan(phi)/L - sin(D)/d) G + 6 tan(D) sin(theta1) / (d^2 cos^2(D) cos^5 theta1),
    F_theta1 = 4 tan(theta1) (tan(phi)/L - sin(D)/d) G + 3 tan^2(D) (1 + 5 tan^2 theta1) / (d^2 cos^4 theta1),
and v2 = z2' = F_phi omega_s + F_D D' + F_theta1 theta1', so the model's inputs are
    v = v1 / (cos D cos theta1),    omega_s = (v2 - F_D D' - F_theta1 theta1') / F_phi.
The inverse state map: theta1 = arctan z4, D = arctan(d z3 cos^3 theta1),
tan(phi) = L (d cos^3(D) cos^4(theta1) (z2 - 3 tan^2(D) sin(theta1) / (d^2 cos^5 theta1)) + sin(D) / d),
theta = theta1 + D, x = z1 + d cos theta1, y = z5 + d sin theta1. The chart needs |theta1| < pi/2,
|D| < pi/2 and |phi| < pi/2. tests/planning/test_trailer_steering.py checks it numerically: the maps round
trip, the chart's Jacobian carries the model's vector fields to the chained ones, and the model
integrated (DOP853) under the mapped inputs follows the chained plan to its end.

Local frames, as for the cars (:mod:`nhstab.planning.car_charts`): :func:`steer_trailer` expresses
both states in a frame (origin, heading alpha), steers there, checks that |theta1 - alpha| stays
below ``theta_limit`` along the steered path, and maps it back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import InputError, require_finite, require_positive
from ..geometry import wrap_angle
from ..models.car_trailer import CarTrailer
from .steering import SteeringPlan, _array, _count, _vector, steer_chained, steer_chained_polynomial

__all__ = ["TrailerSteering", "to_chained", "from_chained", "inputs_from_chained", "chained_inputs", "steer_trailer",
           "TRAILER_MODES"]

#: steering modes for the trailer: the polynomial (v1 constant: no reversal within a piece) and the
#: Murray-Sastry phased sinusoids
TRAILER_MODES = ("polynomial", "phased")


def _kind(model) -> tuple[float, float]:
    """(L, d) of a car_trailer with one trailer."""
    if not isinstance(model, CarTrailer):
        raise InputError("model", "a car_trailer model", getattr(model, "name", model))
    if model.trailers != 1:
        raise InputError("model", "a car_trailer with one trailer (the chained chart here is for N = 1)",
                         f"{model.trailers} trailers")
    return float(model.wheelbase), float(model.hitch_lengths[0])


def to_chained(model, x) -> np.ndarray:
    """car_trailer state(s) (..., 5) to chained coordinates (..., 5) (module docstring). Needs
    |theta1| < pi/2, |theta - theta1| < pi/2, |phi| < pi/2."""
    L, d = _kind(model)
    x = _array("x", x, last=5)
    th, phi, th1 = x[..., 2], x[..., 3], x[..., 4]
    D = wrap_angle(th - th1)
    for label, val in (("heading of the trailer |theta1|", th1), ("hitch angle |theta - theta1|", D),
                       ("steering angle |phi|", phi)):
        if np.any(np.abs(val) >= 0.5 * np.pi):
            raise InputError("x", f"{label} < pi/2 (the chained chart)", f"max {np.abs(val).max():.6g}")
    c1, s1 = np.cos(th1), np.sin(th1)
    cD, tD = np.cos(D), np.tan(D)
    z = np.empty(x.shape)
    z[..., 0] = x[..., 0] - d * c1
    z[..., 1] = (np.tan(phi) / L - np.sin(D) / d) / (d * cD**3 * c1**4) + 3.0 * tD * tD * s1 / (d * d * c1**5)
    z[..., 2] = tD / (d * c1**3)
    z[..., 3] = np.tan(th1)
    z[..., 4] = x[..., 1] - d * s1
    return z


def from_chained(model, z) -> np.ndarray:
    """Chained coordinates (..., 5) to car_trailer state(s) (inverse of :func:`to_chained`)."""
    L, d = _kind(model)
    return _from_chained(L, d, _array("z", z, last=5))


def _from_chained(L: float, d: float, z: np.ndarray) -> np.ndarray:
    th1 = np.arctan(z[..., 3])
    c1, s1 = np.cos(th1), np.sin(th1)
    D = np.arctan(d * z[..., 2] * c1**3)
    cD, tD = np.cos(D), np.tan(D)
    tan_phi = L * (d * cD**3 * c1**4 * (z[..., 1] - 3.0 * tD * tD * s1 / (d * d * c1**5)) + np.sin(D) / d)
    x = np.empty(z.shape)
    x[..., 0] = z[..., 0] + d * c1
    x[..., 1] = z[..., 4] + d * s1
    x[..., 2] = th1 + D
    x[..., 3] = np.arctan(tan_phi)
    x[..., 4] = th1
    return x


def _partials(L: float, d: float, x: np.ndarray):
    """F_phi, F_D, F_theta1 of z2 = F(phi, D, theta1) and the rates D' / v, theta1' / v (docstring)."""
    phi, th1 = x[..., 3], x[..., 4]
    D = x[..., 2] - th1
    c1, t1 = np.cos(th1), np.tan(th1)
    s1 = np.sin(th1)
    cD, sD, tD = np.cos(D), np.sin(D), np.tan(D)
    tp = np.tan(phi)
    G = 1.0 / (d * cD**3 * c1**4)
    k = tp / L - sD / d
    F_phi = G / (L * np.cos(phi) ** 2)
    F_D = -cD * G / d + 3.0 * tD * k * G + 6.0 * tD * s1 / (d * d * cD**2 * c1**5)
    F_t1 = 4.0 * t1 * k * G + 3.0 * tD * tD * (1.0 + 5.0 * t1 * t1) / (d * d * c1**4)
    return F_phi, F_D, F_t1, k, sD / d, cD * c1


def inputs_from_chained(model, z, v) -> np.ndarray:
    """Model inputs (v, omega_s) that realise chained inputs (v1, v2) at chained state z:
    v = v1 / (cos D cos theta1), omega_s = (v2 - F_D D' - F_theta1 theta1') / F_phi."""
    L, d = _kind(model)
    return _inputs(L, d, _array("z", z, last=5), _array("v", v, last=2))


def _inputs(L: float, d: float, z: np.ndarray, v: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
    x = _from_chained(L, d, z) if x is None else x
    F_phi, F_D, F_t1, k, rate1, cc = _partials(L, d, x)
    speed = v[..., 0] / cc
    omega = (v[..., 1] - (F_D * k + F_t1 * rate1) * speed) / F_phi
    return np.stack(np.broadcast_arrays(speed, omega), axis=-1)


def chained_inputs(model, x, u) -> np.ndarray:
    """Inverse input map: state x and inputs (v, omega_s) to chained inputs (v1, v2)."""
    L, d = _kind(model)
    x = _array("x", x, last=5)
    u = _array("u", u, last=2)
    F_phi, F_D, F_t1, k, rate1, cc = _partials(L, d, x)
    v1 = u[..., 0] * cc
    v2 = F_phi * u[..., 1] + (F_D * k + F_t1 * rate1) * u[..., 0]
    return np.stack(np.broadcast_arrays(v1, v2), axis=-1)


@dataclass(frozen=True)
class TrailerSteering:
    """Result of :func:`steer_trailer`: ``t`` (N,), states ``x`` (N, 5) and inputs ``u`` (N, 2) on
    the plan's grid; the largest |phi|, |hitch angle|, |v|, |omega_s| and |theta1 - alpha| on it;
    ``final_error`` = model.state_error(x(T), xf); ``frame`` and ``plan`` (the chained plan in the
    local frame). ``states_at`` / ``inputs_at`` evaluate the exact trajectory at any t in [0, T]."""

    model: object
    x0: np.ndarray
    xf: np.ndarray
    T: float
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    max_abs_phi: float
    max_abs_hitch: float
    max_speed: float
    max_abs_omega_s: float
    max_abs_local_theta1: float
    final_error: np.ndarray
    frame: dict
    plan: SteeringPlan
    _to_world: Callable = field(default=None, repr=False)

    def states_at(self, t) -> np.ndarray:
        L, d = _kind(self.model)
        return self._to_world(_from_chained(L, d, self.plan.states(t)))

    def inputs_at(self, t) -> np.ndarray:
        L, d = _kind(self.model)
        return _inputs(L, d, self.plan.states(t), self.plan.inputs(t))


def _frames(frame, x0, xf):
    origin = np.array([x0[0], x0[1]])
    a0, af = float(x0[4]), float(xf[4])
    options = {"mean": a0 + 0.5 * float(wrap_angle(af - a0)), "start": a0, "goal": af}
    if isinstance(frame, str):
        if frame == "auto":
            return list(options.items()), origin
        if frame in options:
            return [(frame, options[frame])], origin
        if frame == "world":
            return [("world", 0.0)], np.zeros(2)
        raise InputError("frame", "'auto', 'mean', 'start', 'goal', 'world' or a heading in radians", frame)
    return [("heading", require_finite("frame", frame))], origin


def steer_trailer(model, x0, xf, T: float | None = None, frame="auto", *, mode: str = "polynomial",
                  points_per_phase: int = 200, theta_limit: float = 1.2, phase_fractions=None) -> TrailerSteering:
    """Exactly steer a car with one trailer from state x0 to xf through the chained form.

    Both states are expressed in a local frame (origin: x0's position; heading alpha: "mean" of the
    trailer headings, "start", "goal", "world" (alpha = 0), a number, or "auto": the one of mean,
    start, goal whose steered path keeps the smallest max |theta1 - alpha|). ``mode`` "polynomial"
    (:func:`steer_chained_polynomial`: v1 constant, so the trailer's axle never reverses within the
    piece; refused when the goal does not advance along the frame's axis) or "phased"
    (:func:`steer_chained`). ``T`` None picks the shortest time within the model's speed and
    steering-rate limits (inputs scale as 1/T along the same path). Refused with
    :class:`InputError` (on ``xf``) when the path leaves the chart: |theta1 - alpha| reaching
    ``theta_limit``, or the hitch or steering angle reaching pi/2.
    """
    L, d = _kind(model)
    if mode not in TRAILER_MODES:
        raise InputError("mode", "one of " + ", ".join(TRAILER_MODES), mode)
    x0 = _vector("x0", x0, (5,))
    xf = _vector("xf", xf, (5,))
    if T is not None:
        T = require_positive("T", T)
    ppp = _count("points_per_phase", points_per_phase)
    theta_limit = require_positive("theta_limit", theta_limit)
    if theta_limit >= 0.5 * np.pi:
        raise InputError("theta_limit", "below pi/2 rad", theta_limit)

    def chained(z0, zf, T):
        if mode == "polynomial":
            return steer_chained_polynomial(z0, zf, T)
        return steer_chained(z0, zf, T, phase_fractions=phase_fractions)

    frames, origin = _frames(frame, x0, xf)
    best, refusals, tried = None, [], []
    for fname, alpha in frames:
        if alpha in tried:
            continue
        tried.append(alpha)
        ca, sa = math.cos(alpha), math.sin(alpha)

        def to_local(x, ca=ca, sa=sa, alpha=alpha):
            out = np.array(x, dtype=float)
            dx, dy = x[..., 0] - origin[0], x[..., 1] - origin[1]
            out[..., 0], out[..., 1] = ca * dx + sa * dy, -sa * dx + ca * dy
            out[..., 2], out[..., 4] = wrap_angle(x[..., 2] - alpha), wrap_angle(x[..., 4] - alpha)
            return out

        l0, lf = to_local(x0), to_local(xf)
        ends = max(abs(l0[4]), abs(lf[4]))
        if ends >= theta_limit:
            refusals.append(f"{fname}: endpoint |theta1 - alpha| = {ends:.3f}")
            continue
        try:
            z0l, zfl = to_chained(model, l0), to_chained(model, lf)
        except InputError as exc:
            refusals.append(f"{fname}: {exc.expected} ({exc.got})")
            continue
        if mode == "polynomial" and zfl[0] == z0l[0]:
            refusals.append(f"{fname}: the trailer does not advance along the frame's axis (v1 would be 0)")
            continue
        plan = chained(z0l, zfl, 1.0 if T is None else T)
        dense = plan.grid(max(ppp, 1000) if T is None else ppp)
        xl = _from_chained(L, d, plan.states(dense))
        max_th = float(np.abs(xl[:, 4]).max())
        hitch = float(np.abs(xl[:, 2] - xl[:, 4]).max())
        if max_th >= theta_limit or hitch >= 0.5 * np.pi - 1e-9 or not np.all(np.isfinite(xl)):
            refusals.append(f"{fname}: max |theta1 - alpha| = {max_th:.3f}, max |hitch angle| = {hitch:.3f}")
            continue
        if best is None or max_th < best[0]:
            best = (max_th, fname, alpha, plan, l0, dense, xl)
    if best is None:
        raise InputError("xf", f"a goal reachable within the chained chart (|theta1 - alpha| < {theta_limit:g} rad)",
                         xf, detail="; ".join(refusals) or "no frame")
    max_th, fname, alpha, plan, l0, dense, xl = best
    if T is None:
        uu = _inputs(L, d, plan.states(dense), plan.inputs(dense), xl)
        T = max(float(np.abs(uu[:, 0]).max()) / model.max_speed,
                float(np.abs(uu[:, 1]).max()) / model.max_steer_rate) * 1.001
        if not T > 0.0 or not math.isfinite(T):
            T = 1.0
        plan = chained(plan.z0, plan.zf, T)

    ca, sa = math.cos(alpha), math.sin(alpha)
    # the world heading of the local frame's zero (alpha, up to the turns x0's headings carry)
    th_off, th1_off = float(x0[2]) - float(l0[2]), float(x0[4]) - float(l0[4])

    def to_world(xl):
        out = np.array(xl, dtype=float)
        out[..., 0] = origin[0] + ca * xl[..., 0] - sa * xl[..., 1]
        out[..., 1] = origin[1] + sa * xl[..., 0] + ca * xl[..., 1]
        out[..., 2] = xl[..., 2] + th_off
        out[..., 4] = xl[..., 4] + th1_off
        return out

    t = plan.grid(ppp)
    z = plan.states(t)
    xl = _from_chained(L, d, z)
    u = _inputs(L, d, z, plan.inputs(t), xl)
    x = to_world(xl)
    x[0] = x0
    return TrailerSteering(
        model=model, x0=x0, xf=xf, T=float(T), t=t, x=x, u=u, max_abs_phi=float(np.abs(xl[:, 3]).max()),
        max_abs_hitch=float(np.abs(xl[:, 2] - xl[:, 4]).max()), max_speed=float(np.abs(u[:, 0]).max()),
        max_abs_omega_s=float(np.abs(u[:, 1]).max()), max_abs_local_theta1=float(np.abs(xl[:, 4]).max()),
        final_error=model.state_error(x[-1], xf), frame={"name": fname, "origin": origin.copy(), "heading": alpha},
        plan=plan, _to_world=to_world)
