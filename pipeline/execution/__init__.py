"""The composite controller in closed loop: execution, sensing, monitoring, replanning (``nhstab run``)."""

from __future__ import annotations

from .._lazy import lazy_exports

#: public name -> the module that defines it
_NAMES = {
    "RunOptions": ".config",
    "load_run_config": ".config",
    "CONTROLLERS": ".controllers",
    "ControllerOptions": ".controllers",
    "FeedbackLaw": ".controllers",
    "build_law": ".controllers",
    "tvlqr_gains": ".controllers",
    "plan_record": ".outputs",
    "read_run_csv": ".outputs",
    "summary": ".outputs",
    "write_plan": ".outputs",
    "write_run": ".outputs",
    "Plant": ".plant",
    "STATUSES": ".runner",
    "RunResult": ".runner",
    "execute": ".runner",
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _NAMES)
