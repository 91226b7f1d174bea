"""Signal stages: derivatives on real time and low-pass filters, whole or streamed.

Every stage is a stateful object with ``push(stamp_ns, values) -> outputs`` and
``finish() -> the rest`` that gives the same result however the samples are chunked (one push
of a whole log, blocks, or one sample at a time); the whole-log functions ``differentiate`` and
``LowPass.apply`` are one push plus ``finish``. Importing this package does not import scipy.
"""

from twincd.signal.derivatives import (
    DEFAULT_POLYORDER,
    DEFAULT_WINDOW,
    StreamingDerivative,
    differentiate,
)
from twincd.signal.filters import (
    DECAY_TOLERANCE,
    SETTLING_TOLERANCE,
    LowPass,
    StreamingLowPass,
    decay_margin,
    settling_samples,
)
from twincd.signal.stream import (
    DEFAULT_GAP_FACTOR,
    SegmentedStage,
    Segmenter,
    nominal_period,
    seconds_to_ns,
    segment_bounds,
)

__all__ = [
    "DECAY_TOLERANCE",
    "DEFAULT_GAP_FACTOR",
    "DEFAULT_POLYORDER",
    "DEFAULT_WINDOW",
    "SETTLING_TOLERANCE",
    "LowPass",
    "SegmentedStage",
    "Segmenter",
    "StreamingDerivative",
    "StreamingLowPass",
    "decay_margin",
    "differentiate",
    "nominal_period",
    "seconds_to_ns",
    "segment_bounds",
    "settling_samples",
]
