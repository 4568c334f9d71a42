"""``--fit``'s order of tries (nhstab.tubes.fit.fit_plan), on stand-in plans and tubes whose clearances are given:
the margin the tube needs, halfway when that margin is worse, other seeds at the best plan's margin, and a seed
that finds a plan already tried judged once."""

from types import SimpleNamespace

import numpy as np
import pytest
from nhstab.tubes.fit import fit_plan


def _plan(tag: float):
    nom = SimpleNamespace(t=np.linspace(0.0, 1.0, 5), x=np.full((5, 3), float(tag)))
    return SimpleNamespace(status="ok", nominal=nom)


def _tube(clearance: float, need: float | None = None):
    return SimpleNamespace(certified=clearance >= 0.0, certified_clearance=clearance,
                           info={"verdict": {"needed_margin_m": need}})


class _Planner:
    """plan_at(margin, k) -> a plan tagged by what ``table`` says for (rounded margin, k); tube_of -> its tube."""

    def __init__(self, table):
        self.table, self.calls, self.tubes = table, [], 0

    def plan_at(self, mg, k):
        self.calls.append((round(mg, 6), k))
        entry = self.table.get((round(mg, 6), k))
        if entry is None:
            return SimpleNamespace(status="no_path", nominal=None), None
        tag, clearance = entry
        return _plan(tag), SimpleNamespace(tag=tag, clearance=clearance)

    def tube_of(self, law):
        self.tubes += 1
        return _tube(law.clearance)


def _fit(planner, first_clearance, need, cap=0.3, tries=4):
    first = (_plan(0), SimpleNamespace(tag=0), _tube(first_clearance, need))
    return fit_plan(planner.plan_at, planner.tube_of, None, None, margin=0.1, cap=cap, first=first, tries=tries,
                    slack=0.01)


def test_a_worse_plan_at_the_needed_margin_leads_halfway_from_the_best():
    # the needed margin (0.24 + 0.01) finds a plan with a much wider tube; halfway (0.175) certifies
    p = _Planner({(0.25, 0): (1, -2.0), (0.175, 0): (2, 0.004)})
    result, law, tube, margin, record = _fit(p, -0.12, 0.24)
    assert p.calls == [(0.25, 0), (0.175, 0)]
    assert margin == pytest.approx(0.175) and tube.certified and law.tag == 2
    assert record["certified"] is True and "halfway" in record["tries"][record["chosen"]]["try"]


def test_other_seeds_plan_at_the_best_margin_and_repeats_are_judged_once():
    # need and halfway are both worse than the first plan; seeds then plan at the first plan's margin 0.1;
    # seed + 1 finds the first plan again (no new tube), seed + 2 a better one
    p = _Planner({(0.25, 0): (1, -0.5), (0.175, 0): (2, -0.4), (0.1, 1): (0, None), (0.1, 2): (3, -0.05)})
    result, law, tube, margin, record = _fit(p, -0.12, 0.24, tries=4)
    assert p.calls == [(0.25, 0), (0.175, 0), (0.1, 1), (0.1, 2)]
    assert p.tubes == 3                                   # the repeat of the first plan got no tube of its own
    assert record["tries"][3]["status"] == "the same plan as try 0"
    assert law.tag == 3 and margin == pytest.approx(0.1) and record["certified"] is False
    assert tube.certified_clearance == pytest.approx(-0.05)


def test_no_plan_at_the_needed_margin_goes_halfway_and_a_better_plan_moves_the_seeds_there():
    p = _Planner({(0.2, 0): (1, -0.03), (0.2, 1): (2, 0.01)})
    result, law, tube, margin, record = _fit(p, -0.12, 0.4, cap=0.3)   # need capped at the start/goal's 0.3
    assert p.calls == [(0.3, 0), (0.2, 0), (0.2, 1)]
    assert margin == pytest.approx(0.2) and law.tag == 2 and record["certified"] is True


def test_a_better_but_uncertified_needed_margin_skips_halfway():
    p = _Planner({(0.25, 0): (1, -0.02), (0.25, 1): (2, -0.01)})
    result, law, tube, margin, record = _fit(p, -0.12, 0.24, tries=2)
    assert p.calls == [(0.25, 0), (0.25, 1)]
    assert law.tag == 2 and margin == pytest.approx(0.25)
