"""What a sample stream (``twincd.io.stream.samples``) did with a log's JointState messages:
the counts, and the warnings that report them once the log is read."""

from __future__ import annotations

import logging
from dataclasses import dataclass

log = logging.getLogger("twincd")


@dataclass
class StreamCounts:
    """What happened to the JointState messages of a stream."""

    read: int = 0  # messages read on the topic
    incomplete: int = 0  # dropped: a stream joint missing, or a non-finite position
    duplicates: int = 0  # dropped: the exact stamp of an earlier sample
    late: int = 0  # dropped: older than a sample already emitted
    ragged: int = 0  # dropped: filled arrays whose length differs from the names
    clock_back: int = 0  # dropped: behind a backward jump of the clock
    jumps: int = 0  # backward jumps of the clock
    largest_jump_ns: int = 0
    samples: int = 0  # emitted
    unstamped: int = 0  # every header stamp of the topic 0: timed by the log time instead
    foreign: int = 0  # ignored: messages that carry none of the stream's joints
    foreign_names: tuple[str, ...] = ()  # the joints those messages name
    other_publisher: int = 0  # ignored: a second publisher's on the same joints (zeros)
    named_twice: int = 0  # messages naming a joint twice (its first value kept)
    twice_names: tuple[str, ...] = ()

    @property
    def dropped(self) -> int:
        return (
            self.incomplete
            + self.duplicates
            + self.late
            + self.ragged
            + self.clock_back
            + self.other_publisher
        )


def report_counts(
    c: StreamCounts, source: str, topic: str, reorder: int, span_s: float, damage: str | None
) -> None:
    """One warning for each kind of message dropped or ignored on ``topic`` (``reorder``: the
    stream's reorder window; ``span_s``: the seconds its samples span; ``damage``: what was
    damaged in the log, if anything)."""
    if c.ragged:
        log.warning(
            "%s: dropping %d ragged message(s) (filled arrays that do not match the names)",
            source,
            c.ragged,
        )
    if c.jumps:
        log.warning(
            "%s: the clock jumps back %d time(s) (by up to %.3g s); dropping the %d sample(s) "
            "stamped before the time already reached",
            source,
            c.jumps,
            c.largest_jump_ns * 1e-9,
            c.clock_back,
        )
    if c.unstamped:
        log.warning(
            "%s: the samples on %s carry no header stamp (every one is 0); the %d sample(s) "
            "are timed by their log time instead",
            source,
            topic,
            c.unstamped,
        )
    if c.duplicates:
        log.warning(
            "%s: dropping %d sample(s) whose stamp repeats an earlier one",
            source,
            c.duplicates,
        )
    if c.foreign:
        log.warning(
            "%s: ignoring %d message(s) on %s that carry none of its joints (another "
            "publisher's: %s)",
            source,
            c.foreign,
            topic,
            ", ".join(c.foreign_names[:8]),
        )
    if c.other_publisher:
        log.warning(
            "%s: ignoring %d message(s) on %s from a second publisher of the same joints "
            "(every effort exactly 0, between samples of the live one less than 1.5 periods "
            "apart; ≈ %.3g Hz)",
            source,
            c.other_publisher,
            topic,
            c.other_publisher / max(span_s, 1e-9),
        )
    if c.named_twice:
        log.warning(
            "%s: %d message(s) name joint(s) %s twice; keeping the first value of each",
            source,
            c.named_twice,
            ", ".join(c.twice_names),
        )
    if c.incomplete:
        log.warning("%s: dropping %d sample(s) that do not carry every joint", source, c.incomplete)
    if c.late:
        log.warning(
            "%s: dropping %d sample(s) stamped earlier than samples already read "
            "(more than %d samples out of order)",
            source,
            c.late,
            reorder,
        )
    if damage is not None:
        log.warning("%s: %s", source, damage)
