"""Helpers the batch tests share: what a store holds, trial by trial."""
import json

from nhstab.batch.store import Store


def records(db) -> dict:
    """Everything a trial decides (status, metrics, series, seed), by id; wall-clock timings left out."""
    with Store(db) as s:
        return {t["id"]: json.dumps([t["status"], t["metrics"], t["series"], t["seed"]], sort_keys=True)
                for t in s.trials()}
