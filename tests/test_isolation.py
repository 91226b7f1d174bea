"""Collision isolation (twincd/detection/isolation.py): the deepest significant joint names the
link, judged by each joint's residual at the event's peak score over its noise scale; events
carry the link they name."""

from __future__ import annotations

import itertools

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
    residual[45, 2] = 2.0  # its peak score falls in the second block
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


@pytest.mark.parametrize("split", [None, 37, 50])
def test_the_evidence_is_the_residual_at_the_peak_score_in_any_block(split: int | None) -> None:
    """A deeper joint's noise spike away from the push's peak does not make the link deeper (the
    largest magnitude over the event would name link 5), wherever the blocks split the event:
    at 37 the spike sits on the first block's own highest score, so a tracker that kept it
    would name link 5; at 50 a later, lower part must not replace the peak."""
    from twincd.detection.events import EventTracker

    n = 100
    stamps = np.arange(n, dtype=np.int64) * 10_000_000
    residual = np.zeros((n, 7))
    residual[30:60, :3] = np.sin(np.linspace(0.1, 3.0, 30))[:, None] * [8.0, 4.0, 2.0]
    residual[36, 4] = 0.6  # joint 5: 6 noise units, once, early in the event
    scores = (residual**2).sum(axis=1)
    flags = scores > 0.5
    iso = LinkIsolator(LINKS, DEPTHS, SCALE, margin=1.0)
    names = tuple(f"joint{i}" for i in range(1, 8))
    tracker = EventTracker(names, iso)
    cuts = [0, n] if split is None else [0, split, n]
    events = []
    for a, b in itertools.pairwise(cuts):
        events += tracker.push(flags[a:b], scores[a:b], residual[a:b], stamps[a:b])
    events += tracker.finish()
    assert [(e.link, e.peak_ns) for e in events] == [("link3", int(stamps[np.argmax(scores)]))]
    assert iso.link(residual[36]) == "link5"  # what keeping block 1's own peak would name
    assert iso.link(np.abs(residual).max(axis=0)) == "link5"  # and the largest magnitude


def test_the_first_of_equal_peaks_is_kept_even_when_the_callers_buffer_is_reused() -> None:
    """Two equal peak scores in two blocks: the first one's residual names the link (as argmax
    does), and the row is kept, not a view of the caller's block, which is then overwritten."""
    from twincd.detection.events import EventTracker

    n = 60
    stamps = np.arange(n, dtype=np.int64) * 10_000_000
    scores = np.zeros(n)
    scores[10:50] = 2.0
    scores[[20, 40]] = 9.0  # a tie
    residual = np.zeros((n, 7))
    residual[10:50, :3] = [8.0, 4.0, 2.0]
    residual[40, 4] = 0.6  # the second peak's residual names link 5
    tracker = EventTracker(
        tuple(f"joint{i}" for i in range(1, 8)), LinkIsolator(LINKS, DEPTHS, SCALE)
    )
    buffer = np.empty((30, 7))
    events = []
    for a in (0, 30):
        buffer[:] = residual[a : a + 30]
        events += tracker.push(
            scores[a : a + 30] > 1, scores[a : a + 30], buffer, stamps[a : a + 30]
        )
        buffer[:] = np.nan  # the caller reuses its buffer
    events += tracker.finish()
    assert [(e.link, e.peak_ns) for e in events] == [("link3", int(stamps[20]))]


def test_every_model_is_judged_by_one_rule() -> None:
    """detect's scoring stage takes the rule's κ and ρ (the values the docs quote), whatever the
    model; a push whose deepest joint sits at 1.2 κ is named only when ρ < 1.2."""
    from pathlib import Path

    from twincd.calibration import Calibration
    from twincd.detection.detect import ScoringStage
    from twincd.detection.isolation import DEFAULT_KAPPA, DEFAULT_MARGIN

    assert (DEFAULT_KAPPA, DEFAULT_MARGIN) == (2.25, 1.3)  # docs/models-and-results.md: Isolation
    z = np.array([30.0, 20.0, 1.2 * DEFAULT_KAPPA, 1.0, 0.5, 0.1, 0.0])
    rule = LinkIsolator(LINKS, DEPTHS, np.ones(7))
    assert rule.isolate(z) == (None, ("link3", "link2"))
    assert LinkIsolator(LINKS, DEPTHS, np.ones(7), margin=1.1).isolate(z) == ("link3", ("link3",))
    shipped = Path(__file__).resolve().parents[1] / "sample_logs"
    for name in ("calibration.json", "calibration.affine.json"):
        stage = ScoringStage(Calibration.load(shipped / name)).events.isolator
        assert stage is not None and (stage.kappa, stage.margin) == (DEFAULT_KAPPA, DEFAULT_MARGIN)
