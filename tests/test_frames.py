"""twincd.prepare.frames: delayed stages keep every sample's columns together, in any chunking."""

from __future__ import annotations

import itertools
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twincd.prepare.frames import Chain, Derived, Frame, Mapped, prefetched


class Lag:
    """A signal stage that emits each value ``lag`` samples late (x[i] + x[i + lag])."""

    def __init__(self, lag: int) -> None:
        self.lag = lag
        self.buf = np.zeros((0,))

    def push(self, stamp_ns: np.ndarray, values: np.ndarray) -> np.ndarray:
        self.buf = np.concatenate((self.buf, values))
        k = max(len(self.buf) - self.lag, 0)
        out = self.buf[:k] + self.buf[self.lag : self.lag + k]
        self.buf = self.buf[k:]
        return out

    def finish(self) -> np.ndarray:
        out, self.buf = self.buf.copy(), np.zeros((0,))
        return out


def _run(chain: Chain, frame: Frame, cuts: list[int]) -> Frame:
    edges = [0, *sorted(set(c for c in cuts if 0 < c < frame.n)), frame.n]
    parts = [chain.push(frame.tail(a).head(b - a)) for a, b in itertools.pairwise(edges)]
    parts.append(chain.finish())
    return Frame.concat(parts)


@given(
    n=st.integers(1, 60),
    lags=st.lists(st.integers(0, 7), min_size=1, max_size=3),
    cuts=st.lists(st.integers(0, 60), max_size=8),
)
@settings(max_examples=200, deadline=None)
def test_any_chunking_gives_the_whole_answer_with_columns_aligned(
    n: int, lags: list[int], cuts: list[int]
) -> None:
    x = np.arange(n, dtype=float) ** 1.5
    frame = Frame({"stamp_ns": np.arange(n, dtype=np.int64), "x": x, "tag": np.arange(n)})

    def chain() -> Chain:
        stages = []
        src = "x"
        for i, lag in enumerate(lags):
            stages.append(Derived(Lag(lag), src, f"y{i}"))
            src = f"y{i}"
        stages.append(Mapped(lambda f: f.with_columns(z=f[src] * 2)))
        return Chain(stages)

    whole = _run(chain(), frame, [])
    chunked = _run(chain(), frame, cuts)
    assert whole.n == chunked.n == n
    for key in whole:
        np.testing.assert_array_equal(whole[key], chunked[key])
    np.testing.assert_array_equal(chunked["tag"], np.arange(n))  # rows stayed together


def test_a_stage_that_loses_samples_is_an_error() -> None:
    class Lossy(Lag):
        def finish(self) -> np.ndarray:
            return np.zeros((0,))

    stage = Derived(Lossy(3), "x", "y")
    stage.push(Frame({"stamp_ns": np.arange(5), "x": np.ones(5)}))
    with pytest.raises(RuntimeError, match="lost 3"):
        stage.finish()


def test_frame_rejects_ragged_columns() -> None:
    with pytest.raises(ValueError, match="different lengths"):
        Frame({"a": np.zeros(3), "b": np.zeros(4)})


def test_prefetched_gives_the_items_and_their_error_in_order() -> None:
    assert list(prefetched(range(50), depth=3)) == list(range(50))

    def failing():  # type: ignore[no-untyped-def]
        yield 1
        raise ValueError("damaged block")

    got = prefetched(failing())
    assert next(got) == 1
    with pytest.raises(ValueError, match="damaged block"):
        next(got)


@pytest.mark.parametrize("items", [[1, 2], [1, 2, 3, 4]])
def test_leaving_prefetched_early_never_waits_for_ever(items: list[int]) -> None:
    # the consumer leaves (an error, SIGTERM) while the reader waits on a full queue, with its
    # last item or its end marker: the reader must notice, or the leaving join hangs
    got = prefetched(iter(items), depth=1)
    assert next(got) == 1
    time.sleep(0.3)  # the reader fills the queue and blocks on its next put
    closer = threading.Thread(target=got.close, daemon=True)
    closer.start()
    closer.join(timeout=5.0)
    assert not closer.is_alive(), "closing prefetched() hung"
