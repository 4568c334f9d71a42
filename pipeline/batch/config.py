"""The batch config (``nhstab batch CONFIG``): strict YAML, expanded into cells and seeded trials.

Format (paths relative to the config file)::

    name: depot-robustness          # optional, default: the file stem
    root_seed: 2026                 # every trial's seed is spawned from it (numpy SeedSequence)
    trials: 20                      # trials per cell, >= 1
    maps:                           # >= 1
      - path: ../maps/scenarios/depot_blocked_aisle.yaml
        problems: map               # "map" (default): the map's start and goal;
                                    # or a list of {start: [x, y, theta], goal: [x, y, theta]};
                                    # or {first: 0, count: 5}: the map's problems (e.g. from a
                                    # Moving AI .scen file given as the map's base scenarios)
        cell_size: 1.0              # optional: Moving AI maps only
    robots: [unicycle]              # optional, default: each map's robot; each a model name or a
                                    # robot description (the robot: block of nhstab.robot), e.g.
                                    # [unicycle, {model: rwd_car, name: van, wheelbase: 3.0, margin: 0.2}]
    robot: {model: rwd_car, ...}    # optional: one robot (the same as robots: [that]; not with robots)
    controllers: [gramian, open-loop, tvlqr]     # default [gramian]
    grid:                           # every combination is a cell; each list non-empty
      noise: [0.5, 1.0, 2.0]        # noise scale (multiplies every level of run.noise)
      alpha: [0.1, 0.2]             # gramian only (default: the robot's)
      delta: [2.0]
      gamma: [1.0]
      window: [future, frozen-time] # gramian only (default: run.controller.window): future |
                                    # frozen-time (causal) | past (Remark 2: not stabilizing, study only)
    run:                            # base options of every trial: the run-config keys except map,
      rate_hz: 50                   # robot, start, goal and seed (see nhstab run --config)
      noise: {sensor: {x: 0.02}}
      planning: {margin: auto}      # each plan's margin from its error tube (nhstab.tubes)
      tube: {require_certified: true}   # a trial whose plan is not certified ends not_certified

Each trial k of a cell has the seed spawned as child k of ``root_seed``, the same in every cell, so
controllers and noise levels are compared on the same seeds. Trial ids are ``<cell>#<k>``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from .. import bodies
from ..collision import CollisionWorld
from ..control import WINDOWS
from ..errors import InputError, user_keys
from ..examples import resolve_map_path
from ..execution.config import RunOptions, check_number, check_pose, config_mapping, options_from_mapping
from ..execution.controllers import CONTROLLERS
from ..execution.runner import check_run
from ..limits import MAX_BATCH_TRIALS, MAX_GAMMA, MAX_NOISE_SCALE, MAX_SEED, check_int, check_turning_radius
from ..maps.bundled import resolve_config_path
from ..planning import PLANNABLE
from ..records import to_jsonable
from ..robot import map_robot_where, resolve_robot, robot_from_spec
from ..safe_io import read_yaml_mapping
from ..tubes.fit import AUTO_MARGIN_START
from ..yaml_keys import schema_keys, schema_required
from .bundle import MapBundle

# the keys, from the batch config's JSON Schema (nhstab.yaml_keys): the top level, a map entry's, the grid's,
# and the run block's (the run config's but map, robot, start, goal and seed)
_TOP = schema_keys("batch-config")
_REQUIRED = schema_required("batch-config")
_MAP_KEYS = schema_keys("batch-config", "properties", "maps", "items")
_GRID_KEYS = schema_keys("batch-config", "properties", "grid")
_RUN_KEYS = frozenset(schema_keys("batch-config", "properties", "run"))
_RUN_EXCLUDED = ("robot", "start", "goal", "seed")


@dataclass(frozen=True)
class MapSpec:
    path: str
    label: str
    cell_size: float | None
    problems: tuple            # ((start, goal), ...) poses as tuples
    #: SHA-256 of every file the map is built from (nhstab.maps.content_hash): a resumed batch and
    #: every trial check it, so a store never mixes trials of two versions of a map
    content_hash: str = ""
    #: the map as data (every file's bytes, nhstab.batch.bundle): what the trials load their map
    #: from, wherever they run, and what the store keeps for replays
    bundle: object = field(default=None, repr=False, compare=False)
    #: the map as the config names it: ``example:NAME``, else the file's absolute path
    given: str = field(default="", compare=False)


@dataclass
class BatchConfig:
    name: str
    root_seed: int
    trials: int
    maps: list
    robots: list | None
    controllers: list
    grid: dict
    run: dict                  # the raw `run` mapping (validated), kept for the record
    source: str = ""
    base_options: RunOptions = field(default_factory=RunOptions)

    def seeds(self) -> list[int]:
        """Trial k's seed: child k of root_seed (a 32-bit integer, usable as nhstab run --seed). The
        count is bounded by the config check (nhstab.limits.MAX_BATCH_TRIALS) before anything is
        spawned."""
        children = np.random.SeedSequence(self.root_seed).spawn(self.trials)
        return [int(c.generate_state(1)[0]) for c in children]

    def cell_count(self) -> int:
        """len(self.cells()), from the sizes alone: what the trial bound is checked against before
        any cell is made."""
        return cell_count(self.maps, self.robots, self.controllers, self.grid)

    def cells(self) -> list[dict]:
        """Every combination: map, problem, robot, controller, grid values."""
        out = []
        noise = self.grid.get("noise", [1.0])
        for ms in self.maps:
            robots = self.robots or [None]
            for p_index, (start, goal) in enumerate(ms.problems):
                for robot, ctrl in itertools.product(robots, self.controllers):
                    gains = list(itertools.product(self.grid.get("window", [None]), self.grid.get("alpha", [None]),
                                                   self.grid.get("delta", [None]),
                                                   self.grid.get("gamma", [None]))) if ctrl == "gramian" \
                        else [(None, None, None, None)]
                    for (window, alpha, delta, gamma), level in itertools.product(gains, noise):
                        cell = {"map": ms.label, "map_path": ms.path, "map_hash": ms.content_hash,
                                "map_bundle": ms.bundle.id if ms.bundle is not None else None,
                                "cell_size": ms.cell_size,
                                "problem": p_index, "start": list(start), "goal": list(goal),
                                "robot": robot, "controller": ctrl, "alpha": alpha, "delta": delta,
                                "gamma": gamma, "noise": float(level)}
                        if window is not None:          # absent (not None) keeps older cell ids and stores
                            cell["window"] = window
                        cell["id"] = cell_id(cell)
                        out.append(cell)
        return out

    def trial_specs(self) -> list[dict]:
        seeds = self.seeds()
        specs = []
        for cell in self.cells():
            for k, seed in enumerate(seeds):
                specs.append({"id": f"{cell['id']}#{k}", "cell": cell["id"], "trial": k, "seed": seed,
                              "cell_spec": cell, "run": self.run})
        return specs

    def windows(self) -> set:
        """The gramian windows some cell uses (the grid's, else the run config's)."""
        if "gramian" not in self.controllers:
            return set()
        return set(self.grid.get("window") or [self.base_options.controller.window])

    def describe(self) -> dict:
        return {"name": self.name, "root_seed": self.root_seed, "trials": self.trials,
                "maps": [{"path": m.path, "label": m.label, "cell_size": m.cell_size, "problems": m.problems,
                          "content_hash": m.content_hash} for m in self.maps],
                "robots": self.robots, "controllers": self.controllers, "grid": self.grid, "run": self.run,
                "source": self.source}

    def effective(self) -> dict:
        """The config as a batch config with every default filled in: each map's problems spelled out,
        the grid's noise, and every run option (:func:`~nhstab.execution.config.config_mapping`; the
        options left to the robot, such as its margin, planning space and stabilizer, are left out). Loaded again, it
        defines the same cells and seeds, and gives this same mapping."""
        maps = []
        for m in self.maps:
            entry = {"path": m.given or str(Path(m.path).resolve()),
                     "problems": [{"start": [float(v) for v in a], "goal": [float(v) for v in b]}
                                  for a, b in m.problems]}
            if m.cell_size is not None:
                entry["cell_size"] = m.cell_size
            maps.append(entry)
        out = {"name": self.name, "root_seed": self.root_seed, "trials": self.trials, "maps": maps}
        if self.robots is not None:
            out["robots"] = self.robots
        out["controllers"] = list(self.controllers)
        out["grid"] = {"noise": [1.0], **self.grid}
        out["run"] = {k: v for k, v in config_mapping(self.base_options).items() if k not in _RUN_EXCLUDED}
        return to_jsonable(out)

    def bundles(self) -> dict:
        """The maps as data, by bundle id (see nhstab.batch.bundle)."""
        return {m.bundle.id: m.bundle for m in self.maps if m.bundle is not None}

    def n_trials(self) -> int:
        return self.cell_count() * self.trials

    def fingerprint(self) -> str:
        """A hash of everything that decides the trials (not the name, nor where the map files are):
        the options, seeds, problems and the content of every map file (base maps and images
        included), so that a resumed batch must match."""
        d = self.describe()
        d.pop("name")
        d.pop("source")
        for m in d["maps"]:
            m.pop("path")
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:16]


def robot_label(robot) -> str:
    """A cell's robot in ids and reports: the model name, a description's ``name``, or its model and
    a short hash of the description."""
    if robot is None:
        return "default"
    if isinstance(robot, str):
        return robot
    if isinstance(robot.get("name"), str):
        return robot["name"]
    digest = hashlib.sha256(json.dumps(robot, sort_keys=True, default=str).encode()).hexdigest()[:6]
    return f"{robot.get('model')}-{digest}"


def cell_id(cell: dict) -> str:
    parts = [f"map={cell['map']}", f"problem={cell['problem']}", f"robot={robot_label(cell['robot'])}",
             f"controller={cell['controller']}"]
    if cell.get("window") is not None:
        parts.append(f"window={cell['window']}")
    for key in ("alpha", "delta", "gamma"):
        if cell[key] is not None:
            parts.append(f"{key}={cell[key]:g}")
    parts.append(f"noise={cell['noise']:g}")
    return "|".join(parts)


def _list(key, v, minimum=1):
    if not isinstance(v, list) or len(v) < minimum:
        raise InputError(key, f"a list of at least {minimum} item{'s' if minimum != 1 else ''}", v)
    return v


def load_batch_config(path) -> BatchConfig:
    """Read and check a batch config; every map is loaded, and every value checked as each trial would
    check it (:func:`_check_trials`), here, before any trial runs. Raises InputError naming the key.

    Each map is read into a bundle (its files' bytes, :mod:`nhstab.batch.bundle`) and loaded from
    that bundle, exactly as every trial will load it, wherever it runs: a map that cannot travel
    (it names a base map or image by an absolute path) is refused here, naming ``maps[i].path``."""
    path = resolve_config_path(path, "CONFIG", "batch")
    data = read_yaml_mapping(path, "CONFIG", "batch config (YAML)", keys=_TOP, required=_REQUIRED)
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise InputError("name", "a non-empty string", name)

    root_seed = check_int("root_seed", data["root_seed"], 0, MAX_SEED, "a non-negative integer")
    trials = check_int("trials", data["trials"], 1, MAX_BATCH_TRIALS, "a number of trials per cell")
    maps, loaded = [], []
    for i, entry in enumerate(_list("maps", data["maps"])):
        where = f"maps[{i}]"
        if not isinstance(entry, dict) or "path" not in entry:
            raise InputError(where, "a mapping with a path", entry)
        for key in entry:
            if key not in _MAP_KEYS:
                raise InputError(f"{where}.{key}", "one of " + ", ".join(_MAP_KEYS), key)
        if not isinstance(entry["path"], str):
            raise InputError(f"{where}.path", "a path to a map file", entry["path"])
        with user_keys({"example": (f"{where}.path", entry["path"])}):
            mpath = resolve_map_path(entry["path"])      # example:NAME, or relative to the config
        mpath = mpath if mpath.is_absolute() else path.parent / mpath
        cell = check_number(f"{where}.cell_size", entry["cell_size"], 0, lo_open=True) if "cell_size" in entry else None
        try:
            bundle = MapBundle.from_path(mpath, **({"cell_size": cell} if cell is not None else {}))
            m = bundle.load(cell, argument=f"{where}.path")
        except InputError as exc:
            if exc.argument == f"{where}.path":
                raise
            raise InputError(f"{where}.path", "a map that loads", str(entry["path"]), detail=str(exc)) from None
        problems = _problems(f"{where}.problems", entry.get("problems", "map"), m)
        given = entry["path"] if entry["path"].startswith("example:") else str(Path(mpath).resolve())
        maps.append(MapSpec(str(mpath), m.name, cell, problems, m.meta["content_hash"], bundle, given))
        loaded.append(m)
    labels = [m.label for m in maps]
    if len(set(labels)) != len(labels):
        raise InputError("maps", "maps with different names", labels)
    robots = None
    if "robots" in data and "robot" in data:
        raise InputError("robot", "either robot or robots, not both", "both given")
    single = "robot" in data
    if single:
        data = {**data, "robots": [data["robot"]]}
    if "robots" in data:
        robots = _list("robots", data["robots"])
        labels = []
        for j, r in enumerate(robots):
            where = "robot" if single else f"robots[{j}]"
            rob = robot_from_spec(r, where=where)
            if rob.model.name not in PLANNABLE:
                raise InputError(f"{where}.model", "one of " + ", ".join(PLANNABLE), rob.model.name)
            labels.append(robot_label(r))
        if len(set(labels)) != len(labels):
            raise InputError("robots", "robots with different names (give each description a name)", labels)
    controllers = _list("controllers", data.get("controllers", ["gramian"]))
    for j, c in enumerate(controllers):
        if c not in CONTROLLERS:
            raise InputError(f"controllers[{j}]", "one of " + ", ".join(CONTROLLERS), c)
    grid = data.get("grid", {}) or {}
    if not isinstance(grid, dict):
        raise InputError("grid", "a mapping", grid)
    for key, values in grid.items():
        if key not in _GRID_KEYS:
            raise InputError(f"grid.{key}", "one of " + ", ".join(_GRID_KEYS), key)
        _list(f"grid.{key}", values)
        if key == "window":
            for j, v in enumerate(values):
                if v not in WINDOWS:
                    raise InputError(f"grid.window[{j}]", "one of " + ", ".join(WINDOWS), v)
            continue
        lo, lo_open = {"noise": (0.0, False), "alpha": (0.0, True), "delta": (0.0, True), "gamma": (0.5, False)}[key]
        grid[key] = [check_number(f"grid.{key}[{j}]", v, lo, lo_open=lo_open) for j, v in enumerate(values)]
        if key == "noise":                 # the scale's bound (nhstab.limits.MAX_NOISE_SCALE)
            for j, v in enumerate(grid[key]):
                if v > MAX_NOISE_SCALE:
                    raise InputError(f"grid.noise[{j}]", f"a number in [0, {MAX_NOISE_SCALE:g}]", v)
        if key == "gamma":                 # the law's own bound, at load (not once per trial, as an error)
            for j, v in enumerate(grid[key]):
                if v > MAX_GAMMA:
                    raise InputError(f"grid.gamma[{j}]", f"a number in [1/2, {MAX_GAMMA:g}]", v)
    cells = cell_count(maps, robots, controllers, grid)        # before any cell is made
    if cells * trials > MAX_BATCH_TRIALS:
        raise InputError("trials", f"at most {MAX_BATCH_TRIALS:,} trials in the batch (cells x trials)",
                         f"{cells:,} cells x {trials} = {cells * trials:,}")
    run = data.get("run", {}) or {}
    if isinstance(run, dict):
        for key in run:
            if key in _RUN_EXCLUDED:
                raise InputError(f"run.{key}", "set by the batch (maps, robots, trials), not in run", key)
    base = options_from_mapping(run, _RUN_KEYS, prefix="run.")
    config = BatchConfig(name, root_seed, trials, maps, robots, controllers, grid, run, str(path), base)
    _check_trials(config, loaded, single)
    return config


def cell_count(maps, robots, controllers, grid: dict) -> int:
    """The number of cells of a batch (:meth:`BatchConfig.cells`): problems x robots x (for each controller,
    the gramian's grid of windows, alphas, deltas and gammas, one cell for the others) x noise levels."""
    gains = math.prod(len(grid.get(k, [None])) for k in ("window", "alpha", "delta", "gamma"))
    per_problem = sum(gains if c == "gramian" else 1 for c in controllers) * len(grid.get("noise", [1.0]))
    return sum(len(ms.problems) for ms in maps) * len(robots or [None]) * per_problem


def trial_options(spec: dict):
    """The RunOptions of a trial: the batch's base options with the cell's controller, gains, noise
    level, robot and the trial's seed."""
    cell = spec["cell_spec"]
    base = options_from_mapping(spec["run"], prefix="run.")
    ctrl = dataclasses.replace(base.controller, kind=cell["controller"],
                               **{k: cell[k] for k in ("alpha", "delta", "gamma", "window") if cell.get(k) is not None})
    noise = dataclasses.replace(base.noise, scale=base.noise.scale * cell["noise"])
    return dataclasses.replace(base, controller=ctrl, noise=noise, seed=int(spec["seed"]),
                               robot=cell["robot"], start=tuple(cell["start"]), goal=tuple(cell["goal"]))


def _check_trials(config: BatchConfig, loaded: list, single: bool) -> None:
    """What every trial checks before it plans, once per map, robot, controller and combination of the
    grid's gains, before any trial runs: the trial's options as the trial builds them
    (:func:`trial_options`) checked as its run checks them
    (:func:`nhstab.execution.runner.check_run`), and every start and goal (:func:`_check_problems`).
    Errors name the batch config's key: ``grid.delta[0]``, ``run.planning.margin``, ``robots[1].stabilizer.gamma``
    (or the map file's robot key, for a map's own robot)."""
    gain_keys = ("window", "alpha", "delta", "gamma")
    indexed = [list(enumerate(config.grid.get(k) or [None])) for k in gain_keys]
    run_keys = {k: f"run.{k}" for k in (f.name for f in fields(RunOptions)) if k not in _RUN_EXCLUDED}
    for i, (m, spec) in enumerate(zip(loaded, config.maps)):
        for j, r in enumerate(config.robots or [None]):
            where = "robot" if single else f"robots[{j}]"
            rob = resolve_robot(r, m.robot, where=where, map_where=map_robot_where(m))
            if rob.model.name not in PLANNABLE:
                raise InputError(f"maps[{i}].path", f"a map whose robot nhstab plans for ({', '.join(PLANNABLE)})",
                                 rob.model.name, detail="or give robots")
            opts = None
            for controller in config.controllers:
                combos = itertools.product(*indexed) if controller == "gramian" else [[(0, None)] * len(gain_keys)]
                for combo in combos:
                    cell = {"controller": controller, "robot": r, "noise": (config.grid.get("noise") or [1.0])[0],
                            "start": list(spec.problems[0][0]), "goal": list(spec.problems[0][1]),
                            **{k: v for k, (_, v) in zip(gain_keys, combo)}}
                    grid_names = {f"controller.{k}": f"grid.{k}[{jk}]" for k, (jk, v) in zip(gain_keys, combo)
                                  if v is not None}
                    with user_keys(run_keys), user_keys(grid_names):
                        opts = check_run(m, rob, trial_options({"run": config.run, "cell_spec": cell, "seed": 0}))
            _check_problems(f"maps[{i}].problems", m, spec.problems, rob, opts)
            # the planning radius every trial's plan checks (nhstab.limits.check_turning_radius), once here
            given = opts.planning.turning_radius
            key = "run.planning.turning_radius" if given is not None else rob.key("turning_radius")
            try:
                check_turning_radius(key, given if given is not None else rob.turning_radius, m.bounds)
            except InputError as exc:
                raise InputError(exc.argument, exc.expected, exc.got, detail=f"on maps[{i}] ({m.name})") from None


def _check_problems(key: str, m, problems, robot, opts) -> None:
    """Every start and goal inside the map's bounds and clear of its known obstacles by more than
    the planning margin (with ``margin: auto``, the margin its first plan asks for), for the robot's
    footprint: what the first plan of every trial would refuse, refused once here instead of stored as
    an error in every trial."""
    fp = robot.footprint
    margin = opts.planning.margin if opts.planning.margin is not None else robot.margin
    if margin == "auto":                  # the first plan's margin; the search grows it from there
        margin = AUTO_MARGIN_START
    world = None
    for j, (start, goal) in enumerate(problems):
        for which, pose in (("start", start), ("goal", goal)):
            where = f"{key}[{j}].{which}"
            rob_name = robot.name or robot.model.name
            try:                    # the rule every start and goal follows (nhstab.robot.Robot.configuration)
                config = robot.configuration(pose, where)       # the pose or configuration the run plans from
            except InputError as exc:
                raise InputError(where, f"for the {rob_name}: {exc.expected}", exc.got, detail=exc.detail) from None
            if not m.contains(pose[0], pose[1]):
                raise InputError(where, f"a pose inside the bounds of {m.name} {list(m.bounds)}", [float(v) for v in pose])
            world = world or CollisionWorld.from_map(m, "known")
            if robot.trailers:                              # every body of the rig
                x = np.zeros(robot.model.n)
                x[robot.configuration_columns] = config
                c = bodies.clearance(world, robot, x)[0]
            else:
                c = world.clearance(config[:3], fp)
            if c <= margin:
                raise InputError(where, f"a pose more than the planning margin {margin:.3g} m from the known "
                                 f"obstacles of {m.name} for the {rob_name}", [round(float(v), 4) for v in pose],
                                 detail=f"clearance {c:.3g} m")


def _problems(key: str, value, m) -> tuple:
    if value == "map":
        if m.start is None or m.goal is None:
            raise InputError(key, "start/goal pairs (the map gives none)", value)
        return ((tuple(m.start.as_array()), tuple(m.goal.as_array())),)
    if isinstance(value, dict):
        for k in value:
            if k not in ("first", "count"):
                raise InputError(f"{key}.{k}", "first or count", k)
        first = check_number(f"{key}.first", value.get("first", 0), 0, integer=True)
        count = check_number(f"{key}.count", value.get("count", 1), 1, integer=True)
        if first + count > len(m.problems):
            have = (f"{m.name} has no start/goal problems" if not m.problems else
                    f"{m.name} has {len(m.problems)}, numbered from 0")
            raise InputError(key, f"first + count at most the number of the map's problems ({len(m.problems)})",
                             value, detail=have)
        return tuple((tuple(p.start.as_array()), tuple(p.goal.as_array())) for p in m.problems[first:first + count])
    items = _list(key, value)
    out = []
    for j, item in enumerate(items):
        if not isinstance(item, dict) or set(item) != {"start", "goal"}:
            raise InputError(f"{key}[{j}]", "a mapping with start and goal", item)
        out.append((check_pose(f"{key}[{j}].start", item["start"]), check_pose(f"{key}[{j}].goal", item["goal"])))
    return tuple(out)
