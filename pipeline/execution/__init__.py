"""The composite controller in closed loop: execution, sensing, monitoring, replanning (``nhstab run``)."""

from .config import RunOptions, load_run_config
from .controllers import CONTROLLERS, ControllerOptions, FeedbackLaw, build_law, tvlqr_gains
from .outputs import plan_record, read_run_csv, summary, write_plan, write_run
from .plant import Plant
from .runner import STATUSES, RunResult, execute

__all__ = ["RunOptions", "load_run_config", "CONTROLLERS", "ControllerOptions", "FeedbackLaw", "build_law",
           "tvlqr_gains", "read_run_csv", "summary", "write_run", "write_plan", "plan_record", "Plant", "STATUSES", "RunResult", "execute"]
