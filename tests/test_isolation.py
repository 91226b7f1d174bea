"""Collision isolation (twincd/detection/isolation.py): the deepest significant joint names the
link, judged against each joint's training scale; events carry the link they name."""

from __future__ import annotations

import numpy as np
import pytest

from twincd.detection.events import find_events
from twincd.detection.isolation import LinkIsolator, isolator_for
from twincd.twin.robot import child_links, load_robot

LINKS = tuple(f"link{i}" for i in range(1, 8))
DEPTHS = tuple(range(1, 8))
SCALE = np.array([1.0, 1.0, 0.5, 0.5, 0.1, 0.1, 0.01])


def test_the_deepest_significant_joint_names_the_link():
    iso = LinkIsolator(LINKS, DEPTHS, SCALE, kappa=3.0, margin=1.0)  # always names one
    # a push on link 4: large on joints 1-4, noise-sized beyond
    assert iso.link(np.array([20.0, 9.0, 3.0, 1.6, 0.2, 0.1, 0.02])) == "link4"
    # the same magnitude is significant on a quiet joint and not on a noisy one
    assert iso.link(np.array([20.0, 9.0, 3.0, 1.6, 0.4, 0.1, 0.02])) == "link5"
    assert iso.link(np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])) is None  # nothing significant
    # depth decides, not the joint order of the calibration
    shuffled = LinkIsolator(LINKS[::-1], DEPTHS[::-1], SCALE[::-1], kappa=3.0, margin=1.0)
    assert shuffled.link(np.array([0.02, 0.1, 0.2, 1.6, 3.0, 9.0, 20.0])) == "link4"
    assert isolator_for(None, DEPTHS, SCALE) is None
    assert isolator_for(LINKS, DEPTHS, None) is None


def test_a_link_is_named_only_when_the_evidence_singles_it_out():
    iso = LinkIsolator(LINKS, DEPTHS, np.ones(7), kappa=3.0, margin=1.5)
    # joint 3 clearly loaded (8 ≥ 4.5), joint 4 clearly quiet (1 < 2): link 3
    assert iso.isolate(np.array([20.0, 9.0, 8.0, 1.0, 0.5, 0.1, 0.0])) == ("link3", ("link3",))
    # joints 3 and 4 equally significant, both just above κ: which is the deepest real one
    # cannot be told; the rule's answer first, then the shallower link it names at κ × ρ
    link, candidates = iso.isolate(np.array([20.0, 9.0, 3.3, 3.3, 0.5, 0.1, 0.0]))
    assert link is None and candidates == ("link4", "link2")
    # joint 4 just below κ: a deeper link is likely (a push that reads one link short)
    link, candidates = iso.isolate(np.array([20.0, 9.0, 8.0, 2.8, 0.5, 0.1, 0.0]))
    assert link is None and candidates == ("link3", "link4")
    # nothing significant: no link, the most significant joint's child first
    assert iso.isolate(np.array([2.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]))[0] is None
    # the same evidence at ρ = 1 is always named
    sure = LinkIsolator(LINKS, DEPTHS, np.ones(7), kappa=3.0, margin=1.0)
    assert sure.link(np.array([20.0, 9.0, 3.3, 3.3, 0.5, 0.1, 0.0])) == "link4"


def test_child_links_follow_the_kinematic_tree():
    robot = load_robot("xarm7")
    links, depths = child_links(robot, robot.joint_names)
    assert links == LINKS and depths == DEPTHS
    links, depths = child_links(robot, ("joint3", "joint1"))
    assert links == ("link3", "link1") and depths == (3, 1)


@pytest.mark.parametrize("split", [None, 37])
def test_events_name_the_link_across_blocks(split: int | None) -> None:
    n = 100
    stamps = np.arange(n, dtype=np.int64) * 10_000_000
    residual = np.zeros((n, 7))
    residual[30:60, :3] = [4.0, 2.0, 1.0]  # a push on link 3
    residual[45, 2] = 2.0  # its largest magnitude falls in the second block
    residual[80:90, :6] = 1.0  # link 6: joint 6 is 10 σ off
    scores = (residual**2).sum(axis=1)
    flags = scores > 0
    iso = LinkIsolator(LINKS, DEPTHS, SCALE, margin=1.0)
    names = tuple(f"joint{i}" for i in range(1, 8))
    if split is None:
        events = find_events(flags, scores, residual, stamps, names, iso)
    else:
        from twincd.detection.events import EventTracker

        tracker = EventTracker(names, iso)
        events = tracker.push(flags[:split], scores[:split], residual[:split], stamps[:split])
        events += tracker.push(flags[split:], scores[split:], residual[split:], stamps[split:])
        events += tracker.finish()
    assert [e.link for e in events] == ["link3", "link6"]
    assert events[0].to_dict()["link"] == "link3"


def test_detect_weighs_the_evidence_with_the_models_own_rule() -> None:
    """A model with speed bins (its evidence whitened) gets its κ and ρ; the other models theirs:
    a push whose deepest joint sits at 1.25 κ is named by the first's rule only when ρ < 1.25."""
    from twincd.detection.isolation import (
        DEFAULT_MARGIN,
        KAPPA_BY_SPEED,
        MARGIN_BY_SPEED,
        kappa_for,
        margin_for,
    )

    assert kappa_for("identified-whitened", "depth") == KAPPA_BY_SPEED
    assert margin_for("depth") == MARGIN_BY_SPEED and margin_for("sum") == DEFAULT_MARGIN
    assert kappa_for("identified-whitened") == 3.25 and kappa_for("affine") == 3.0
    peaks = np.array([30.0, 20.0, 1.25 * KAPPA_BY_SPEED, 1.0, 0.5, 0.1, 0.0])
    speed = LinkIsolator(LINKS, DEPTHS, np.ones(7), KAPPA_BY_SPEED, margin_for("depth"))
    flat = LinkIsolator(LINKS, DEPTHS, np.ones(7), KAPPA_BY_SPEED, margin_for("sum"))
    assert speed.isolate(peaks) == (None, ("link3", "link2"))
    assert flat.isolate(peaks) == ("link3", ("link3",))
    # and detect's scoring stage takes the rule of the calibration it scores
    from pathlib import Path

    from twincd.calibration import Calibration
    from twincd.detection.detect import ScoringStage

    shipped = Path(__file__).resolve().parents[1] / "sample_logs"
    for name, margin in (("calibration.json", MARGIN_BY_SPEED), ("calibration.affine.json", 1.2)):
        rule = ScoringStage(Calibration.load(shipped / name)).events.isolator
        assert rule is not None and rule.margin == margin
