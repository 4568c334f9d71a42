"""The limits nhstab puts on what it is given, in one place, each with its reason.

Every entry point (command line, run and batch configs, map files, library calls) checks its input
against these before it allocates or computes anything that grows with them, and refuses what is
beyond them with one :class:`~nhstab.errors.InputError` naming the key, the limit and the value.
docs/reference/limits.md lists them (tests/test_hostile_input.py holds the two equal).
"""

from __future__ import annotations

import math

from .errors import InputError, number_hint

# ---- files ------------------------------------------------------------------------------------
#: the fraction of the input limits a nominal is planned within (``nhstab run``'s ``headroom`` and
#: ``nhstab plan --headroom``): the rest is left to the feedback
DEFAULT_HEADROOM = 0.8
#: largest YAML document (map, run config, batch config, ROS map metadata) [bytes]: the bundled ones
#: are a few kB, and 1 MiB holds about 50,000 polygon vertices (parsed in a few seconds);
#: geometry beyond this belongs in an occupancy image or a Moving AI file
MAX_YAML_BYTES = 1024 * 1024
#: deepest nesting of YAML collections: the formats need at most 6 levels; this stays far below
#: Python's recursion limit, which a deeper document (e.g. 3000 nested lists) would exhaust
MAX_YAML_DEPTH = 64
#: most YAML nodes a document may expand to, with every alias counted as a copy of what it names:
#: a 1 MiB document has fewer nodes than this, so only alias bombs ("billion laughs") reach it
MAX_YAML_NODES = 2_000_000
#: largest other input file (map image, Moving AI map, SVG, scenario list, trajectory CSV/NPZ) [bytes]:
#: a 4096 x 4096 16-bit PGM is 32 MiB, its plain-text (P2) form about 100 MiB
MAX_FILE_BYTES = 256 * 1024 * 1024

# ---- maps ---------------------------------------------------------------------------------------
#: largest coordinate magnitude anywhere in a map (bounds, shapes, grid corners, poses) [m]: 1000 km.
#: Keeps every product of coordinates (areas, FCL's bounding volumes) far from overflow
MAX_COORD_M = 1e6
#: finest and coarsest occupancy-grid cell [m]. Below 0.1 mm the cell is smaller than FCL's
#: tolerances; above 1 km one cell is larger than any map a robot plans on
MIN_CELL_M = 1e-4
MAX_CELL_M = 1e3
#: most cells of one occupancy grid: 4096 x 4096. A grid is read into float64 planes of the image
#: (about 40 bytes per cell while it is decoded), so this bounds a map's memory to about 0.7 GB
MAX_GRID_CELLS = 4096 * 4096

#: most FCL objects in one collision world (convex parts of the shapes, plus the rectangles a grid's
#: occupied cells merge into): each costs about 40 us to build and the distance field's raster is
#: drawn from them, so this bounds a world's construction to a few seconds. A grid that exceeds it
#: is mostly isolated noise cells: clean or coarsen it
MAX_WORLD_OBJECTS = 100_000

#: most vertices of one polygon: a map's polygon obstacle (a line of n points is a ring of 2 (n - 1)
#: vertices, so at most 5,001 points) or a robot's footprint. GEOS's simplicity test and its
#: triangulation compare the edges whose bounding boxes overlap: near-linear on a traced outline of
#: short edges, but quadratic on a ring of long parallel edges (a comb of diagonal teeth), about 1 s
#: each at 10,000 vertices and 20 s at 40,000
MAX_POLYGON_VERTICES = 10_000

#: largest heading magnitude in a pose given as input (start, goal, a trailer's heading) [rad]: headings
#: are taken modulo 2 pi, and beyond this a float's spacing (1e-10 rad at 1e6) starts to blur them; a
#: heading of 1e308 has no angle at all (its neighbouring floats are 1e292 rad apart)
MAX_HEADING_RAD = 1e6

# ---- runs ---------------------------------------------------------------------------------------
#: controller rate [Hz]. Every control period runs the law, the plant's RK4 substeps and the
#: monitors in Python (tens of microseconds); at 1 kHz a 60 s run is already 60,000 periods and the
#: zero-order hold is far finer than any robot's dynamics. Below 1 Hz a period is longer than the
#: robots take to cross their own footprint
MIN_RATE_HZ = 1.0
MAX_RATE_HZ = 1000.0
#: RK4 steps of the plant per control period: 4 already integrate to 1e-10 (tested)
MAX_SUBSTEPS = 100
#: most control periods one run may simulate (max_time_s x rate_hz): the run's log keeps about
#: 0.5 kB per period in memory, so this bounds it to about 1 GB
MAX_CONTROL_PERIODS = 2_000_000
#: seeds are non-negative integers below 2**128 (numpy SeedSequence entropy; every stream of a run
#: is derived from it, so no information of a larger seed could be used anyway)
MAX_SEED = 2**128 - 1
#: OMPL seeds its generator with a 32-bit value (nhstab passes seed + 1, and OMPL refuses 0)
MAX_PLANNER_SEED = 2**31 - 2

# ---- batches ----------------------------------------------------------------------------------
#: most trials in one batch (cells x trials per cell): each is a full run of seconds, and the batch
#: keeps every trial's spec and the stored ids in memory (about 1 kB each)
MAX_BATCH_TRIALS = 1_000_000
#: a map as data (nhstab.batch.bundle: every file it is built from, shipped to the workers and kept
#: in the store): at most this many bytes unpacked, and this many files. A map reads at most a few
#: files (YAML, base maps nested 4 deep, one image or scenario list each); the byte bound is an
#: image at the file limit with its YAML files, and stops a "zip bomb" in a store before it is
#: unpacked
MAX_BUNDLE_BYTES = 2 * MAX_FILE_BYTES
MAX_BUNDLE_FILES = 64
#: most trials per cell of the tube study (``nhstab tubes study --trials``): a cell simulates all its
#: trials at once and keeps their series (states, measurements, inputs, errors), measured at 0.17 MB
#: per trial for the study's longest plan (1852 control periods), so about 0.9 GB at this count
MAX_STUDY_TRIALS = 5_000
#: most rollouts of one sampled error tube (N >= ln(1 - confidence) / ln(p); nhstab.tubes.sampled): the
#: rollouts run in chunks of 4,096 whatever N is, so this bounds time, not memory: about 1 s per 1,000
#: rollouts of a 30 s car plan here, so a few minutes at the limit; p = 0.9999 at confidence 0.999 needs
#: 69,075
MAX_ROLLOUTS = 100_000

#: largest probability p of an error tube: the linear tube's radius is the chi-square quantile at
#: q = 1 - (1 - p) / 2, which rounds to 1 (an infinite radius) when 1 - p is near float precision
#: (p = 1 - 1e-16); at 1 - 1e-9 it is 6.2 standard deviations, where the linear-Gaussian model's tails
#: are already beyond anything measured, and a sampled tube would need 3e9 rollouts (MAX_ROLLOUTS)
MAX_PROBABILITY = 1 - 1e-9
#: largest noise scale (``--noise``, ``noise.scale``, a batch grid's ``noise``) and noise level (a
#: standard deviation or impulse in ``noise:``, in its state's unit): the default levels are centimetres
#: and hundredths of a radian, so 1,000 times them are tens of metres, beyond the maps a robot plans on;
#: a level of 1e6 (the coordinate bound) at that scale keeps every squared error far from overflow,
#: where 1e300 made the errors infinite and the runs NaN
MAX_NOISE_SCALE = 1e3
MAX_NOISE_LEVEL = MAX_COORD_M

# ---- gain schedules ---------------------------------------------------------------------------
#: most integration substeps per nominal time step for the gramian's windows: a window of length delta
#: is integrated in steps of at most delta / 16 (StabilizerOptions.max_substep_fraction), so this
#: refuses windows shorter than 1/64 of the nominal's time step (0.3 ms at 0.02 s), where the gramian is
#: numerically singular anyway (a 1e-4 s window already is, on a unicycle's plan), instead of
#: allocating stage arrays of the nominal's length times 12 stages times 1e10 substeps (--delta 1e-12)
MAX_WINDOW_SUBSTEPS = 1024
#: largest gain factor gamma (Proposition 1 needs gamma >= 1/2; the paper uses 1/2 and 1). The gains
#: grow with it and the closed loop stiffens, so its simulation slows down (far beyond this bound, a
#: paper case runs for many minutes), and at 1e300 the gains overflow
MAX_GAMMA = 1e4

#: longest gramian window of ``nhstab paper`` (``--delta``) [s]: the paper's windows are 1 s and Remark 2's
#: grid reaches 4 s; a case keeps about 3.5 kB per sample of its 500 Hz nominal over [0, T + delta]
#: (schedule, dense run, bound checks), so about 0.2 GB at this window (0.7 GB and 40 s at 400 s)
MAX_PAPER_DELTA_S = 100.0

# ---- planning ---------------------------------------------------------------------------------
#: most samples of a nominal's grid (its duration / dt): the run follows it at its control rate, so a
#: longer one could not be run (MAX_CONTROL_PERIODS), and the grid, its gain schedule and its error
#: tube keep a few hundred bytes per sample. Reached by a speed far too low for the map (a tiny
#: --max-speed, or a unicycle's tiny turning radius, which caps its speed at the turn-rate limit
#: times the radius), before anything of that size is allocated
MAX_NOMINAL_SAMPLES = 2_000_000
#: smallest turning radius of a car (wheelbase / tan(max_steer), so max_steer <= atan(wheelbase / this)) [m]:
#: the local paths (Reeds-Shepp, Dubins) are solved in units of the radius and their joins checked to
#: 1e-6 m, which a radius near float precision (max_steer within 1e-16 of pi/2) cannot meet; at 1 mm a
#: crossing of the largest map (2,800 km) is 3e9 radii
MIN_TURNING_RADIUS_M = 1e-3
#: the largest planning turning radius is the map's diagonal (:func:`check_turning_radius`): a larger turn
#: does not fit in the map, and the local paths sample their arcs, whose length grows with the radius

#: the assumed cost of one validity check that reaches FCL [s] (the slow case: measured at about 64 us,
#: see `nhstab bench planning`). A planning budget must afford one crossing of the map at the
#: checking resolution at this cost, or the map is refused before anything is built
FCL_CHECK_S = 64e-6


def nominal_grid(duration: float, dt: float, key: str, value, speed: float, why: str = "") -> int:
    """The number of samples of a nominal lasting ``duration`` on a grid of step ``dt``, or an
    InputError naming ``key`` (what set the ``speed`` [m/s] that made it this long; ``why`` says how)."""
    n = duration / dt + 1.0 if duration >= 0 else math.nan
    if not (math.isfinite(n) and n <= MAX_NOMINAL_SAMPLES):
        raise InputError(key, f"large enough that the nominal fits {MAX_NOMINAL_SAMPLES:,} samples of {dt:g} s",
                         value, detail=f"at {speed:.3g} m/s{why} the nominal would last {duration:.3g} s")
    return max(2, int(math.ceil(duration / dt)) + 1)


def check_probability(key: str, value) -> float:
    """A tube's probability p in (0, MAX_PROBABILITY], or an InputError naming ``key``."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and 0.0 < value <= MAX_PROBABILITY
    if not ok:
        raise InputError(key, f"a number in (0, {MAX_PROBABILITY!r}] (1 - 1e-9)", value, detail=number_hint(value))
    return float(value)


def check_turning_radius(key: str, radius: float, bounds) -> float:
    """A planning turning radius of at most the diagonal of the map's ``bounds`` (xmin, ymin, xmax, ymax)."""
    xmin, ymin, xmax, ymax = bounds
    diagonal = math.hypot(xmax - xmin, ymax - ymin)
    if not radius <= diagonal:
        raise InputError(key, f"at most the map's diagonal, {diagonal:.4g} m (a larger turn does not fit in the map)",
                         radius)
    return float(radius)


def check_headings(key: str, values) -> None:
    """The headings of a pose given as input (every value after x, y) within +-MAX_HEADING_RAD."""
    for i, v in enumerate(values[2:], start=2):
        if not abs(float(v)) <= MAX_HEADING_RAD:
            raise InputError(f"{key}[{i}]", f"a heading within +-{MAX_HEADING_RAD:g} rad", v)


def check_int(key: str, value, lo: int, hi: int, what: str = "an integer") -> int:
    """``value`` as an int in [lo, hi], or an InputError naming ``key``. Works for integers of any
    size (no conversion to float); integral floats are accepted."""
    import numpy as np

    v = None
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        v = int(value)
    elif isinstance(value, (float, np.floating)) and math.isfinite(value) and float(value).is_integer():
        v = int(value)
    if v is None or not lo <= v <= hi:
        raise InputError(key, f"{what} in [{_fmt_int(lo)}, {_fmt_int(hi)}]", _short_int(value),
                         detail=number_hint(value))
    return v


def check_range(key: str, value, lo: float, hi: float, unit: str = "") -> float:
    """``value`` as a finite float in [lo, hi], or an InputError naming ``key`` (with the YAML hint
    for text like ``1e9``)."""
    import numpy as np

    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    v = math.nan
    if ok:
        try:
            v = float(value)
        except OverflowError:
            v = math.inf
    if not (math.isfinite(v) and lo <= v <= hi):
        u = f" {unit}" if unit else ""
        raise InputError(key, f"a number in [{lo:g}, {hi:g}]{u}", _short_int(value), detail=number_hint(value))
    return v


def _fmt_int(v: int) -> str:
    for minus in (0, 1, 2):
        k = (v + minus).bit_length() - 1
        if v >= 10**6 and v + minus == 2**k:
            return f"2**{k}" + (f" - {minus}" if minus else "")
    return f"{v:,}" if abs(v) >= 10**4 else str(v)


def _short_int(value):
    """Huge integers shown by their size, not their hundreds of digits."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**18:
        return f"an integer of about {int(abs(value).bit_length() * math.log10(2)) + 1} digits"
    return value
