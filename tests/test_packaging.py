"""Packaging: one import name (nhstab), the bundled examples as package data, a light command line.

The wheel test builds the wheel, installs it into a fresh virtual environment outside the checkout
and runs the installed console script from a temporary folder. The environment gets nhstab from the
wheel only; its dependencies (numpy, ompl, fcl, ...) are made visible from the test's own
environment by a .pth line, so that the test needs no download of them (the check is about what the
wheel installs, not about pip's resolver).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import nhstab
import pytest
from click.testing import CliRunner
from nhstab.cli.main import cli
from nhstab.errors import InputError
from nhstab.examples import data_root, example_path, list_examples, resolve_map_path
from nhstab.maps import load_map

ROOT = Path(__file__).resolve().parents[1]


def test_pyproject_lists_every_package_folder():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    dirs = cfg["package-dir"]
    assert dirs == {"nhstab": "pipeline", "nhstab.cli": "cli", "nhstab.data": "maps"}
    found = {"nhstab.data"}
    for top, name in (("pipeline", "nhstab"), ("cli", "nhstab.cli")):
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top).parts
            found.add(".".join((name, *rel)))
    assert listed == found


def test_version_lives_in_one_place():
    from nhstab._version import __version__

    assert nhstab.__version__ == __version__
    assert "version" not in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    res = CliRunner().invoke(cli, ["--version"])
    assert __version__ in res.output


def test_public_api_names_resolve_and_are_documented():
    for name in nhstab.__all__:
        obj = getattr(nhstab, name)
        if name != "__version__":
            assert obj.__doc__, name
            assert name in nhstab.__doc__ or name in ("Map", "PlanResult", "Nominal", "RunResult", "PipelineError",
                                                      "InputError"), name
    with pytest.raises(AttributeError):
        nhstab.no_such_name  # noqa: B018


def test_help_imports_no_numpy_scipy_or_matplotlib():
    code = ("import sys; from nhstab.cli.main import cli\n"
            "try:\n    cli.main(['--help'], standalone_mode=False)\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('numpy', 'scipy', 'matplotlib', 'ompl', 'fcl', 'yaml') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.strip().splitlines()[-1] == "[]"


def test_cli_choices_match_the_library():
    from nhstab.cli.options import END_STRATEGY_CHOICES, WINDOW_CHOICES
    from nhstab.control import END_STRATEGIES, WINDOWS

    assert tuple(WINDOWS) == WINDOW_CHOICES and tuple(END_STRATEGIES) == END_STRATEGY_CHOICES


def test_library_never_changes_the_matplotlib_backend():
    code = ("import matplotlib; matplotlib.use('svg'); import numpy as np\n"
            "import nhstab.report, nhstab.report.maps, nhstab.report.runs, nhstab.batch.report\n"
            "from nhstab.report import subplots\n"
            "fig, ax = subplots(figsize=(2, 2)); ax.plot([0, 1], [0, 1])\n"
            "import io; b = io.BytesIO(); fig.savefig(b, format='png'); assert b.getvalue()[:4] == b'\\x89PNG'\n"
            "import matplotlib.pyplot as plt; assert plt.get_fignums() == [], plt.get_fignums()\n"
            "print(matplotlib.get_backend())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "svg"


# ---- examples ------------------------------------------------------------------------------------

def test_examples_cover_every_bundled_map_with_unique_names():
    items = list_examples()
    names = [e.name for e in items]
    assert len(names) == len(set(names))
    assert all("/" not in n for n in names), "a name collision was resolved by folder: rename a file"
    scen = {p.stem for p in (data_root() / "scenarios").glob("*.yaml")}
    assert scen <= set(names)
    for e in items:
        assert e.path.is_file() and e.kind in ("scenario", "problems", "map")
        assert e.description and "(does not load" not in e.description, e
    kinds = {e.name: e.kind for e in items}
    assert kinds["depot_blocked_aisle"] == "scenario" and kinds["warehouse_aisle_a2"] == "scenario"
    assert kinds["parking3"] == "problems" and kinds["depot"] == "map"
    assert "car" not in names and "warehouse_robot" not in names      # footprints, not maps


def test_example_prefix_loads_the_bundled_map_anywhere(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    m = load_map("example:depot_blocked_aisle")
    assert m.name == "depot-blocked-aisle" and len(m.unknown_obstacles) == 1
    assert resolve_map_path(Path("example:parking3")) == example_path("parking3")
    with pytest.raises(InputError, match="depot_blocked_aisle"):
        load_map("example:no_such_map")


def test_examples_command_lists_every_example():
    res = CliRunner().invoke(cli, ["examples", "--json"])
    assert res.exit_code == 0, res.output
    listed = json.loads(res.output)
    assert [e["name"] for e in listed] == [e.name for e in list_examples()]
    res = CliRunner().invoke(cli, ["examples"])
    assert res.exit_code == 0 and "depot_blocked_aisle" in res.output and "Scenarios" in res.output


def test_unknown_example_is_one_line_exit_2():
    res = CliRunner().invoke(cli, ["map", "info", "example:nope"])
    assert res.exit_code == 2
    assert len(res.output.strip().splitlines()) == 1 and "nhstab examples" in res.output


def test_scheduler_without_dask_says_what_to_install(tmp_path, monkeypatch):
    import importlib.util

    from nhstab.batch import runner

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "distributed" else real(name, *a))
    cfg = tmp_path / "b.yaml"
    cfg.write_text("root_seed: 0\ntrials: 1\nmaps: [{path: 'example:cluttered_room'}]\n")
    res = CliRunner().invoke(cli, ["batch", str(cfg), "--out", str(tmp_path / "out"), "--scheduler", "tcp://x:1"])
    assert res.exit_code == 2, res.output
    assert "pip install 'nhstab[cluster]'" in res.output and len(res.output.strip().splitlines()) == 2  # + the header
    assert not (tmp_path / "out" / "trials.sqlite").exists()
    assert runner.require_dask is not None


# ---- the wheel -----------------------------------------------------------------------------------

@pytest.mark.slow
def test_wheel_installs_one_import_name_and_runs_examples_from_anywhere(tmp_path):
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(ROOT)],
                   check=True, capture_output=True, cwd=tmp_path)
    wheel = next(dist.glob("nhstab-*.whl"))
    env_dir = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env_dir)], check=True)
    py = env_dir / "bin" / "python"
    site = Path(subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    # --ignore-installed: pip must not take this environment's own nhstab (a regular install in CI) as
    # already satisfying the wheel
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "--ignore-installed",
                    "-q", str(wheel)], check=True, capture_output=True) if _pip_has_python_option() else \
        subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site), str(wheel)],
                       check=True, capture_output=True)
    top = {p.name for p in site.iterdir()}
    # the dependencies from this environment, written after the install so that pip never saw them
    # (after the venv's own site-packages on sys.path)
    (site / "_nhstab_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    assert "nhstab" in top
    assert not {"pipeline", "cli", "maps", "tests"} & top, top
    assert (site / "nhstab" / "data" / "scenarios" / "depot_blocked_aisle.yaml").is_file()
    assert (site / "nhstab" / "data" / "nav2" / "depot.pgm").is_file()
    assert (site / "nhstab" / "data" / "configs" / "depot_robustness.yaml").is_file()    # example:NAME configs
    assert {p.name for p in (site / "nhstab" / "schemas").glob("*.schema.json")} == \
        {p.name for p in (ROOT / "pipeline" / "schemas").glob("*.schema.json")}            # the YAML formats' schemas

    work = tmp_path / "elsewhere"
    work.mkdir()
    (work / "pipeline.py").write_text("raise SystemExit('the local pipeline.py was imported')\n")
    (work / "cli.py").write_text("raise SystemExit('the local cli.py was imported')\n")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    run = lambda *args: subprocess.run([py, *args], cwd=work, env=env, capture_output=True, text=True)  # noqa: E731
    r = run("-c", "import nhstab, nhstab.planning, nhstab.cli.main; print(nhstab.__file__)")
    assert r.returncode == 0, r.stderr
    assert str(site) in r.stdout
    script = env_dir / "bin" / "nhstab"          # the console script the wheel installs
    nh = [str(script)] if script.is_file() else [str(py), "-m", "nhstab.cli.main"]
    r = subprocess.run([*nh, "examples", "--json"], cwd=work, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    names = {e["name"] for e in json.loads(r.stdout)}
    assert {p.stem for p in (ROOT / "maps" / "scenarios").glob("*.yaml")} <= names
    assert {e.name for e in list_examples()} == names
    r = subprocess.run([*nh, "run", "example:depot_blocked_aisle", "--out", "run1"], cwd=work, env=env,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    summary = json.loads((work / "run1" / "run.json").read_text())
    assert summary["status"] == "reached"
    assert "nanobind" not in r.stderr and "Traceback" not in r.stderr


def _pip_has_python_option() -> bool:
    out = subprocess.run([sys.executable, "-m", "pip", "--version"], capture_output=True, text=True).stdout
    major, minor = map(int, re.match(r"pip (\d+)\.(\d+)", out).groups())
    return (major, minor) >= (22, 3)


@pytest.mark.slow
def test_the_python_guide_example_runs(tmp_path):
    """The Python guide's example (docs/guide/python.md), executed as written (from another folder)."""
    text = (ROOT / "docs" / "guide" / "python.md").read_text()
    code = re.search(r"# Using nhstab from Python.*?```python\n(.*?)```", text, re.S).group(1)
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    lines = res.stdout.strip().splitlines()
    assert lines[0].startswith("ok ") and lines[-1].startswith("reached")
    assert (tmp_path / "run1" / "run.json").is_file()


def test_the_quick_start_run_writes_where_git_does_not_track():
    """The README's Quick start run writes into a folder git ignores, outside the committed results, so
    running it leaves ``git status`` clean."""
    block = re.search(r"## Quick start.*?```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    run = block.strip().splitlines()[0]
    out = re.search(r"nhstab run \S+ --out (\S+)$", run).group(1)
    assert not out.startswith("results")
    if not (ROOT / ".git").exists():
        pytest.skip("not a git clone")
    for name in ("run.json", "trajectory.csv", "run_map.png", "run_tracking.png", "nhstab-manifest.json"):
        res = subprocess.run(["git", "check-ignore", "-q", f"{out}/{name}"], cwd=ROOT)
        assert res.returncode == 0, f"{out}/{name} is not ignored by git"


def test_ci_runs_the_quick_start_test_command():
    """.ci/run runs the README's Quick start test command (the second of its two), word for word."""
    block = re.search(r"## Quick start.*?```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    commands = block.strip().splitlines()
    assert len(commands) == 2 and "pytest" in commands[1]
    assert commands[1] in (ROOT / ".ci" / "run").read_text().splitlines()
