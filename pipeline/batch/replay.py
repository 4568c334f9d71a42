"""One stored trial made ready to run again (``nhstab batch replay``): its map, options and robot.

:func:`prepare_replay` reads the trial from a store, recovers its map (from the store, or for a store
that keeps no maps from the path the trial records, checked against the recorded content hash),
rebuilds the trial's exact run config and loads it back as ``nhstab run --config`` would.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import yaml

from ..errors import InputError
from ..execution import RunOptions
from ..execution.config import load_run_config
from ..maps.base import Map
from ..maps.yaml_format import is_file
from ..robot import Robot, resolve_robot
from .bundle import MapBundle
from .store import Store
from .trial import replay_config


@dataclass(frozen=True)
class Replay:
    """A stored trial ready to run: the trial's record, its map bundle (``from_store``: whether the
    store held it, else it was read at the recorded path) and its files' place ``map_rel`` beside the
    config, the config's text (``run_config.yaml``), the options it gives, and the map."""

    trial_id: str
    store_path: Path
    record: dict
    bundle: MapBundle
    from_store: bool
    map_rel: str
    config_text: str
    options: RunOptions
    map: Map

    @property
    def robot(self) -> Robot:
        """The trial's robot: the config's, else the map's ``robot:`` block."""
        return resolve_robot(self.options.robot, self.map.robot, source="run config")

    @property
    def files(self) -> dict:
        """The files a replay writes beside the run's: run_config.yaml and the map's under map/."""
        return {"run_config.yaml": self.config_text, **{f"map/{rel}": data for rel, data in self.bundle.files.items()}}


def prepare_replay(store_path, trial_id: str, notify: Callable[[str], None] | None = None) -> Replay:
    """The trial ``trial_id`` of the store at ``store_path`` (a batch folder or its trials.sqlite, opened
    read-only) made ready to run. ``notify`` receives a note when the store records no map content
    (the map at the recorded path is used as it is now). Errors are :class:`InputError` naming
    ``TRIAL_ID`` or ``STORE``."""
    store_path = Path(store_path)
    path = store_path / "trials.sqlite" if store_path.is_dir() else store_path
    with Store(path) as store:
        record = store.trial(trial_id)
        if record is None:
            raise InputError("TRIAL_ID", "the id of a stored trial (see the report's CSV)", trial_id)
        cell = _cell_spec(record, trial_id)
        bundle = store.map_bundle(cell.get("map_bundle"), cell.get("map_hash"))
        schema = store.schema
    from_store = bundle is not None
    if bundle is None:
        bundle = bundle_at_recorded_path(cell, path, schema, notify)
    map_rel = "map/" + bundle.entry
    try:
        cfg = replay_config(record, map_rel)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError("TRIAL_ID", "a trial whose stored spec is complete", trial_id,
                         detail=f"{type(exc).__name__}: {exc}") from None
    text = "# replays trial " + trial_id + " of " + str(path) + "\n" + yaml.safe_dump(cfg, sort_keys=False)
    with tempfile.TemporaryDirectory(prefix="nhstab-replay-") as tmp:
        bundle.write_into(Path(tmp) / "map")
        cfg_path = Path(tmp) / "run_config.yaml"
        cfg_path.write_text(text, encoding="utf-8")
        _, opts = load_run_config(cfg_path)
    m = bundle.load(cell.get("cell_size"), argument="STORE")
    return Replay(trial_id=trial_id, store_path=path, record=record, bundle=bundle, from_store=from_store,
                  map_rel=map_rel, config_text=text, options=opts, map=m)


def _cell_spec(record: dict, trial_id: str) -> dict:
    cell = (record.get("spec") or {}).get("cell_spec") if isinstance(record.get("spec"), dict) else None
    if not isinstance(cell, dict) or not isinstance(cell.get("map_path"), str):
        raise InputError("TRIAL_ID", "a trial whose stored spec is complete", trial_id, detail="no cell_spec.map_path")
    return cell


def bundle_at_recorded_path(cell: dict, store_path: Path, schema: int,
                            notify: Callable[[str], None] | None = None) -> MapBundle:
    """For a trial whose map the store does not hold: its files at the recorded path ``cell["map_path"]``,
    checked against the recorded content hash if there is one (else ``notify`` gets a note); an
    :class:`InputError` naming ``STORE`` says what is missing."""
    why = ("it was made before stores kept maps (schema 1)" if schema < 2 else
           f"it holds no map {cell.get('map_bundle') or '(the trial names none)'}")
    where = Path(cell["map_path"])
    expected = "a store that holds the trial's map, or the map files at the path the trial records"
    if not is_file(where):
        raise InputError("STORE", expected, str(store_path), detail=f"{why}, and {where} is not a file here")
    size = cell.get("cell_size")
    bundle = MapBundle.from_path(where, **({"cell_size": size} if size else {}))
    digest = cell.get("map_hash")
    if digest and bundle.content_hash != digest:
        raise InputError("STORE", expected, str(store_path),
                         detail=f"{why}, and {where} has changed since the batch: content hash "
                                f"{bundle.content_hash[:12]}, the trial's {digest[:12]}")
    if not digest and notify is not None:
        notify(f"nhstab: note: {store_path} records no map content; replaying with {where} as it is now")
    return bundle
