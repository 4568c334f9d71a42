"""Options shared by several commands."""

from __future__ import annotations

from pathlib import Path

import click

#: where plan, run and batch write when --out is not given: out/COMMAND in the current folder (the
#: repository's .gitignore ignores out/, so a run from the clone leaves the committed results/ alone)
OUT_ROOT = Path("out")
WINDOW_CHOICES = ("future", "past", "frozen-time")


def out_option(command: str, what: str):
    """``--out DIR`` of plan, run and batch: ``what`` the folder holds; default ``out/COMMAND``."""
    return click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
                        default=OUT_ROOT / command, show_default=True, help=f"Folder for {what}.")
END_STRATEGY_CHOICES = ("frozen", "extend")


def stabilizer_options(defaults: bool = True):
    """--alpha, --delta, --gamma, --window, --end-strategy. With ``defaults=False`` they default to
    None (meaning: keep the case's own value)."""

    # the choices, spelled out here so that ``nhstab --help`` needs no numpy or scipy
    # (tests/cli/test_cli.py checks them against nhstab.control.WINDOWS and END_STRATEGIES)
    windows, end_strategies = WINDOW_CHOICES, END_STRATEGY_CHOICES

    def deco(f):
        f = click.option("--end-strategy", type=click.Choice(end_strategies), default="frozen" if defaults else None,
                         help="What P is where the window runs off the trajectory: frozen, the last whole "
                              "window carried along the flow; extend, the window slides on along the nominal's "
                              "continuation under its last input, or its last real move where it ends at rest "
                              "(the cars' default; see docs/theory/control-law.md).")(f)
        f = click.option("--window", type=click.Choice(windows), default="future" if defaults else None,
                         help="future: P_c = H_c(t, t+delta)^-1 (Proposition 1); frozen-time: the causal law "
                              "(Proposition 1 on A(t), B(t) frozen); past: P_r (Remark 2), NOT stabilizing in "
                              "general, for study only.")(f)
        f = click.option("--gamma", type=float, default=1.0 if defaults else None, help="Gain factor, >= 1/2.")(f)
        f = click.option("--delta", type=float, default=1.0 if defaults else None, help="Window length [s], > 0.")(f)
        f = click.option("--alpha", type=float, default=0.1 if defaults else None, help="Rate parameter, > 0.")(f)
        return f

    return deco


def collect(**values) -> dict:
    """Drop the options left at None."""
    return {k: v for k, v in values.items() if v is not None}


def robot_options(f):
    """--robot NAME and --robot-config FILE (a robot description, see nhstab.robot)."""
    f = click.option("--robot-config", "robot_config", type=click.Path(path_type=Path), default=None,
                     help="Robot description (YAML: model, parameters, footprint, margin, ...); overrides --robot. "
                          "A Nav2 parameters file (nav2_params.yaml, or nav2:FILE) gives the footprint, the model "
                          "and turning radius of its Smac planner and the speed limits; --robot then sets the "
                          "model.")(f)
    f = click.option("--robot", default=None,
                     help="Robot model with its built-in description: unicycle, rwd_car, fwd_car, car_trailer "
                          "(default: the config's, else the map's robot block, else unicycle); or nav2:FILE, the "
                          "robot of a Nav2 parameters file (as --robot-config nav2:FILE).")(f)
    return f


def cli_robot(robot_name, robot_config, config_robot=None, map_robot=None, m=None):
    """The robot of a command: --robot-config, else --robot, else the run config's, else the map's
    (``m``, the map, names its file in errors)."""
    from nhstab.errors import InputError
    from nhstab.robot import load_robot, map_robot_where, resolve_robot, robot_from_spec

    if robot_config is None and robot_name is not None and robot_name.startswith("nav2:"):
        robot_config, robot_name = Path(robot_name), None
    if robot_config is not None:
        nav2 = _nav2_file(robot_config)
        if nav2 is None:
            return load_robot(robot_config)
        from nhstab.nav2 import NAV2_MODELS, read_nav2_robot

        if robot_name is not None and robot_name not in NAV2_MODELS:
            raise InputError("--robot", "with a Nav2 parameters file, one of " + ", ".join(NAV2_MODELS), robot_name)
        got = read_nav2_robot(nav2, model=robot_name)
        for line in got.lines:
            click.echo(f"nav2: {line}", err=True)
        return got.robot
    if robot_name is not None:
        try:
            return robot_from_spec(robot_name, where="--robot", source="--robot")
        except InputError as exc:
            raise exc.renamed("--robot", got=robot_name) from None
    if config_robot is not None:
        return robot_from_spec(config_robot, where="robot", source="run config")
    return resolve_robot(None, map_robot, map_where=map_robot_where(m) if m is not None else "robot")


def _nav2_file(robot_config) -> Path | None:
    """The Nav2 parameters file a --robot-config names (``nav2:FILE``, or a YAML file whose nodes hold
    ``ros__parameters``), else None (an nhstab robot file)."""
    from nhstab.errors import InputError
    from nhstab.nav2 import NAV2_PREFIX, is_nav2_params
    from nhstab.safe_io import load_yaml_file

    text = str(robot_config)
    if text.startswith(NAV2_PREFIX):
        return Path(text[len(NAV2_PREFIX):])
    try:
        data = load_yaml_file(Path(text), "--robot-config", "robot description (YAML)")
    except InputError:
        return None                  # load_robot reports it
    return Path(text) if is_nav2_params(data) else None


def effective_doc(m, map_path: str, robot, start, goal, robot_key: str = "robot",
                  pose_names: tuple[str, str] = ("start", "goal")) -> dict:
    """The head of an effective config (``--print-config`` of plan and run): the map as given, the
    robot's full description and the start and goal configurations, the robot checked plannable and the
    poses checked against it (errors name ``robot_key`` and ``pose_names``)."""
    from nhstab.errors import InputError
    from nhstab.planning import PLANNABLE

    if robot.model.name not in PLANNABLE:
        raise InputError(robot_key, "one of " + ", ".join(PLANNABLE) + " (the robots nhstab plans for)",
                         robot.model.name)
    start, goal = robot.configuration(start, pose_names[0]), robot.configuration(goal, pose_names[1])
    return {"map": map_path, "robot": robot.spec(), "start": [float(v) for v in start],
            "goal": [float(v) for v in goal]}


def effective_yaml(header: str, doc: dict) -> str:
    """An effective config as ``--print-config`` prints it: the ``# header`` line, then ``doc`` as YAML
    in its own key order."""
    import yaml

    return f"# {header}\n" + yaml.safe_dump(doc, sort_keys=False)


def numbers(option: str, text: str, what: str) -> list[float]:
    """The comma-separated numbers of a command-line option, else an InputError naming ``option``
    (``what``: what it expects)."""
    try:
        return [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        from nhstab.errors import InputError

        raise InputError(option, what, text) from None


def echo_suite_write(result: dict, out_dir, check: bool, command: str, full: str | None = None) -> int:
    """Print what a suite's ``write_suite`` did (``nhstab parking suite``, ``nhstab trailer suite``): the files
    written, or with ``check`` whether the folder is what the command (``full``, else ``nhstab COMMAND
    suite --out OUT``) writes; the exit code."""
    if check:
        bad = {k: v for k, v in result.items() if v}
        if bad:
            for key, names in bad.items():
                click.echo(f"{key}: {', '.join(names)}")
            click.echo(f"{out_dir} is not what `{full or f'nhstab {command} suite --out {out_dir}'}` writes", err=True)
            return 1
        click.echo(f"{out_dir} is up to date")
        return 0
    click.echo(f"wrote {len(result['written'])} files into {out_dir}")
    return 0
