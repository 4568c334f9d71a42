"""Shortest Reeds-Shepp and Dubins paths between two poses, and their samples, with numpy.

The same local paths as OMPL's ``ReedsSheppStateSpace`` and ``DubinsStateSpace`` (the shortest of the
path families of Reeds and Shepp 1990, and of Dubins 1957), computed here so that a path can be
sampled at many arc lengths in one vectorised call instead of one ``space.interpolate`` per point
(tests/planning/test_local_paths.py checks the lengths against OMPL's ``distance`` and the samples against its
``interpolate``).

A path is a list of segments ``(kind, length)``: kind "L" (turn left), "R" (turn right) or "S"
(straight), length signed (negative: driven in reverse), in units of the turning radius. Poses are
(x, y, theta); samples are spaced uniformly in arc length, as OMPL interpolates.

Reeds-Shepp words, in normalised coordinates (turning radius 1) of the goal in the start's frame
(x, y, phi), are the five base families CSC, CCC, CCCC, CCSC and CCSCC (formulas 8.1 to 8.11 of the
paper) combined with the three symmetries: time flip (x, y, phi) -> (-x, y, -phi) with every length
negated, reflection (x, y, phi) -> (x, -y, -phi) with L and R swapped, and for the asymmetric families
driving the path backwards, (x, y, phi) -> (x cos phi + y sin phi, x sin phi - y cos phi, phi) with the
segments in reverse order.
"""

from __future__ import annotations

import math

import numpy as np

_TWO_PI = 2.0 * math.pi
_ZERO = 10 * np.finfo(float).eps


def _mod2pi(a: float) -> float:
    """a wrapped to (-pi, pi]."""
    v = math.fmod(a, _TWO_PI)
    if v < -math.pi:
        v += _TWO_PI
    elif v > math.pi:
        v -= _TWO_PI
    return v


def _polar(x: float, y: float) -> tuple[float, float]:
    return math.hypot(x, y), math.atan2(y, x)


def _tau_omega(u: float, v: float, xi: float, eta: float, phi: float) -> tuple[float, float]:
    delta = _mod2pi(u - v)
    a = math.sin(u) - math.sin(delta)
    b = math.cos(u) - math.cos(delta) - 1.0
    t1 = math.atan2(eta * a - xi * b, xi * a + eta * b)
    t2 = 2.0 * (math.cos(delta) - math.cos(v) - math.cos(u)) + 3.0
    tau = _mod2pi(t1 + math.pi) if t2 < 0 else _mod2pi(t1)
    return tau, _mod2pi(tau - u + v - phi)


# ---- the base families: each returns the segment lengths (t, u, v[, w[, z]]) or None ----------------
def _lsl(x, y, phi):                                  # L+ S+ L+ (8.1)
    u, t = _polar(x - math.sin(phi), y - 1.0 + math.cos(phi))
    if t >= -_ZERO:
        v = _mod2pi(phi - t)
        if v >= -_ZERO:
            return t, u, v
    return None


def _lsr(x, y, phi):                                  # L+ S+ R+ (8.2)
    u1, t1 = _polar(x + math.sin(phi), y - 1.0 - math.cos(phi))
    u1 *= u1
    if u1 >= 4.0:
        u = math.sqrt(u1 - 4.0)
        t = _mod2pi(t1 + math.atan2(2.0, u))
        v = _mod2pi(t - phi)
        if t >= -_ZERO and v >= -_ZERO:
            return t, u, v
    return None


def _lrl(x, y, phi):                                  # L+ R- L (8.3)
    xi, eta = x - math.sin(phi), y - 1.0 + math.cos(phi)
    u1, theta = _polar(xi, eta)
    if u1 <= 4.0:
        u = -2.0 * math.asin(0.25 * u1)
        t = _mod2pi(theta + 0.5 * u + math.pi)
        v = _mod2pi(phi - t + u)
        if t >= -_ZERO and u <= _ZERO:
            return t, u, v
    return None


def _lrlr_equal(x, y, phi):                           # L+ R+ L- R- (8.7), middle lengths u, -u
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho = 0.25 * (2.0 + math.hypot(xi, eta))
    if rho <= 1.0:
        u = math.acos(rho)
        t, v = _tau_omega(u, -u, xi, eta, phi)
        if t >= -_ZERO and v <= _ZERO:
            return t, u, -u, v
    return None


def _lrlr_opposite(x, y, phi):                        # L+ R- L- R+ (8.8), middle lengths u, u
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho = (20.0 - xi * xi - eta * eta) / 16.0
    if 0.0 <= rho <= 1.0:
        u = -math.acos(rho)
        if u >= -0.5 * math.pi:
            t, v = _tau_omega(u, u, xi, eta, phi)
            if t >= -_ZERO and v >= -_ZERO:
                return t, u, u, v
    return None


def _lrsl(x, y, phi):                                 # L+ R-(pi/2) S- L- (8.9)
    xi, eta = x - math.sin(phi), y - 1.0 + math.cos(phi)
    rho, theta = _polar(xi, eta)
    if rho >= 2.0:
        r = math.sqrt(rho * rho - 4.0)
        u = 2.0 - r
        t = _mod2pi(theta + math.atan2(r, -2.0))
        v = _mod2pi(phi - 0.5 * math.pi - t)
        if t >= -_ZERO and u <= _ZERO and v <= _ZERO:
            return t, -0.5 * math.pi, u, v
    return None


def _lrsr(x, y, phi):                                 # L+ R-(pi/2) S- R- (8.10)
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho, theta = _polar(-eta, xi)
    if rho >= 2.0:
        t = theta
        u = 2.0 - rho
        v = _mod2pi(t + 0.5 * math.pi - phi)
        if t >= -_ZERO and u <= _ZERO and v <= _ZERO:
            return t, -0.5 * math.pi, u, v
    return None


def _lrslr(x, y, phi):                                # L+ R-(pi/2) S- L-(pi/2) R+ (8.11)
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho, _ = _polar(xi, eta)
    if rho >= 2.0:
        u = 4.0 - math.sqrt(rho * rho - 4.0)
        if u <= _ZERO:
            t = _mod2pi(math.atan2((4.0 - u) * xi - 2.0 * eta, -2.0 * xi + (u - 4.0) * eta))
            v = _mod2pi(t - phi)
            if t >= -_ZERO and v >= -_ZERO:
                return t, -0.5 * math.pi, u, -0.5 * math.pi, v
    return None


_SWAP = {"L": "R", "R": "L", "S": "S"}

#: (base family, its word, driven backwards?) in the order the shortest is chosen (OMPL's order, so that
#: an exact tie between two words is broken the same way)
_FAMILIES = (
    (_lsl, "LSL", False), (_lsr, "LSR", False),
    (_lrl, "LRL", False), (_lrl, "LRL", True),
    (_lrlr_equal, "LRLR", False), (_lrlr_opposite, "LRLR", False),
    (_lrsl, "LRSL", False), (_lrsr, "LRSR", False), (_lrsl, "LRSL", True), (_lrsr, "LRSR", True),
    (_lrslr, "LRSLR", False),
)


def reeds_shepp(start, goal, radius: float) -> list[tuple[str, float]]:
    """The shortest Reeds-Shepp path from pose ``start`` to pose ``goal`` for a turning radius
    ``radius`` > 0: a list of segments (kind, signed length in units of ``radius``)."""
    dx, dy = float(goal[0]) - float(start[0]), float(goal[1]) - float(start[1])
    th0 = float(start[2])
    c, s = math.cos(th0), math.sin(th0)
    x, y = (c * dx + s * dy) / radius, (-s * dx + c * dy) / radius
    phi = float(goal[2]) - th0
    cp, sp = math.cos(phi), math.sin(phi)
    xb, yb = x * cp + y * sp, x * sp - y * cp          # the goal seen driving the path backwards
    best, best_len = None, math.inf
    for fn, word, backwards in _FAMILIES:
        xx, yy = (xb, yb) if backwards else (x, y)
        for flip, refl in ((False, False), (True, False), (False, True), (True, True)):
            a, b, f = (-xx if flip else xx), (-yy if refl else yy), (-phi if flip != refl else phi)
            seg = fn(a, b, f)
            if seg is None:
                continue
            total = sum(abs(v) for v in seg)
            if total < best_len:
                kinds = [(_SWAP[k] if refl else k) for k in word]
                lengths = [(-v if flip else v) for v in seg]
                if backwards:
                    kinds, lengths = kinds[::-1], lengths[::-1]
                best, best_len = list(zip(kinds, lengths)), total
    if best is None:          # cannot happen for finite input (CSC always exists in some variant)
        raise ValueError(f"no Reeds-Shepp path from {start} to {goal}")
    return best


def dubins(start, goal, radius: float) -> list[tuple[str, float]]:
    """The shortest Dubins (forward only) path from ``start`` to ``goal`` for turning radius ``radius``."""
    dx, dy = float(goal[0]) - float(start[0]), float(goal[1]) - float(start[1])
    d = math.hypot(dx, dy) / radius
    th = math.atan2(dy, dx) if d > 0 else 0.0
    a = (float(start[2]) - th) % _TWO_PI
    b = (float(goal[2]) - th) % _TWO_PI
    sa, sb, ca, cb = math.sin(a), math.sin(b), math.cos(a), math.cos(b)
    cab = math.cos(a - b)
    cands = []
    p2 = 2.0 + d * d - 2.0 * cab + 2.0 * d * (sa - sb)                  # LSL
    if p2 >= 0:
        t0 = math.atan2(cb - ca, d + sa - sb)
        cands.append(("LSL", ((t0 - a) % _TWO_PI, math.sqrt(p2), (b - t0) % _TWO_PI)))
    p2 = 2.0 + d * d - 2.0 * cab + 2.0 * d * (sb - sa)                  # RSR
    if p2 >= 0:
        t0 = math.atan2(ca - cb, d - sa + sb)
        cands.append(("RSR", ((a - t0) % _TWO_PI, math.sqrt(p2), (t0 - b) % _TWO_PI)))
    p2 = -2.0 + d * d + 2.0 * cab + 2.0 * d * (sa + sb)                 # LSR
    if p2 >= 0:
        p = math.sqrt(p2)
        t0 = math.atan2(-ca - cb, d + sa + sb) - math.atan2(-2.0, p)
        cands.append(("LSR", ((t0 - a) % _TWO_PI, p, (t0 - b) % _TWO_PI)))
    p2 = -2.0 + d * d + 2.0 * cab - 2.0 * d * (sa + sb)                 # RSL
    if p2 >= 0:
        p = math.sqrt(p2)
        t0 = math.atan2(ca + cb, d - sa - sb) - math.atan2(2.0, p)
        cands.append(("RSL", ((a - t0) % _TWO_PI, p, (b - t0) % _TWO_PI)))
    q = (6.0 - d * d + 2.0 * cab + 2.0 * d * (sa - sb)) / 8.0          # RLR
    if abs(q) <= 1.0:
        p = (_TWO_PI - math.acos(q)) % _TWO_PI
        t0 = (a - math.atan2(ca - cb, d - sa + sb) + 0.5 * p) % _TWO_PI
        cands.append(("RLR", (t0, p, (a - b - t0 + p) % _TWO_PI)))
    q = (6.0 - d * d + 2.0 * cab + 2.0 * d * (sb - sa)) / 8.0          # LRL
    if abs(q) <= 1.0:
        p = (_TWO_PI - math.acos(q)) % _TWO_PI
        t0 = (-a - math.atan2(ca - cb, d + sa - sb) + 0.5 * p) % _TWO_PI
        cands.append(("LRL", (t0, p, ((b - a) % _TWO_PI - t0 + p) % _TWO_PI)))
    word, seg = min(cands, key=lambda c_: sum(c_[1]))
    return list(zip(word, seg))


def local_path(space: str | None, start, goal, radius: float) -> list[tuple[str, float]]:
    """The shortest local path from ``start`` to ``goal``: Dubins for ``space`` "dubins", else (reeds_shepp,
    or None: the default space) Reeds-Shepp; (kind, signed length in radius units) per segment."""
    return dubins(start, goal, radius) if space == "dubins" else reeds_shepp(start, goal, radius)


def path_length(segments, radius: float) -> float:
    return radius * sum(abs(v) for _, v in segments)


def _advance(x, y, th, kind: str, length):
    """The pose after driving ``length`` (signed, radius 1 units; arrays broadcast) of one segment."""
    if kind == "S":
        return x + length * np.cos(th), y + length * np.sin(th), th + 0.0 * length
    if kind == "L":
        return x + np.sin(th + length) - np.sin(th), y - np.cos(th + length) + np.cos(th), th + length
    return x - np.sin(th - length) + np.sin(th), y + np.cos(th - length) - np.cos(th), th - length


def sample(start, segments, radius: float, fractions) -> np.ndarray:
    """Poses (len(fractions), 3) at the given fractions in [0, 1] of the path's arc length (theta not
    wrapped: continuous along the path)."""
    f = np.clip(np.asarray(fractions, dtype=float), 0.0, 1.0)
    lengths = np.array([abs(v) for _, v in segments])
    total = float(lengths.sum())
    out = np.empty((len(f), 3))
    x0, y0, th0 = float(start[0]), float(start[1]), float(start[2])
    if total <= 0.0:
        out[:] = (x0, y0, th0)
        return out
    s = f * total
    ends = np.cumsum(lengths)
    seg_of = np.minimum(np.searchsorted(ends, s, side="right"), len(segments) - 1)
    # the pose at the start of every segment (in units of the radius, about the start's position)
    px, py, pth = 0.0, 0.0, th0
    for k, (kind, v) in enumerate(segments):
        sel = seg_of == k
        if sel.any():
            begin = ends[k] - lengths[k]
            part = np.minimum(s[sel] - begin, lengths[k]) * (1.0 if v >= 0 else -1.0)
            qx, qy, qth = _advance(px, py, pth, kind, part)
            out[sel, 0], out[sel, 1], out[sel, 2] = qx, qy, qth
        px, py, pth = (float(a) for a in _advance(px, py, pth, kind, v))
    out[:, 0] = x0 + radius * out[:, 0]
    out[:, 1] = y0 + radius * out[:, 1]
    return out


def sample_every(start, segments, radius: float, step: float, include_start: bool = True) -> np.ndarray:
    """Poses along the path every at most ``step`` metres (uniform in arc length), the end included."""
    total = path_length(segments, radius)
    n = max(1, int(math.ceil(total / step)))
    k = np.arange(0 if include_start else 1, n + 1)
    return sample(start, segments, radius, k / n)
