"""Defaults every stage shares, in a module that imports nothing, so that the CLI can show them
in ``--help`` without loading numpy, scipy or Pinocchio."""

DEFAULT_ROBOT = "xarm7"  # the seed paper's arm
DEFAULT_TOPIC = "/joint_states"
DEFAULT_LABEL_TOPIC = "/collision_flag"
DEFAULT_LINK_TOPIC = "/collision_link"
DEFAULT_SIM_TOPIC = "/twincd/sim_effort"

# Chosen on train/val data only (studies/choose_cutoff.py): best F1 over μ + iσ peaks at 1 Hz
# for the zero-phase filter and at 3 Hz for the causal one, whose lag grows as the cut-off falls.
DEFAULT_ORDER = 2
DEFAULT_CUTOFF_HZ = 1.0
# The identified models and the best model (fit without --model) filter with a critically damped
# filter at this cut-off (studies/real_arm_statistics.py --cutoff, studies/real_arm.py
# --fit-args "--cutoff …"): on the real arm's six rotations 1 / 1.5 / 2 Hz found 160 / 161 / 163
# of 169 pushes with 1 / 1 / 2 false alarms, AUC 0.971 / 0.975 / 0.975; on synth seed 2 AUC
# 0.862 / 0.866 and 6 / 4 false alarms at 1 / 1.5 Hz.
DEFAULT_CRITICAL_CUTOFF_HZ = 1.5
DEFAULT_CAUSAL_CUTOFF_HZ = 3.0
# the fast band's upper edge: where a hand strike's energy still is (a 0.1–0.7 s controller
# answer, 1–10 Hz), chosen on injected contacts of three real arms (docs/models-and-results.md)
DEFAULT_FAST_CUTOFF_HZ = 10.0

DEFAULT_K_SIGMA = 4.0  # the paper's μ + 4σ
# `threshold`'s budget for the default models (scored by the depth statistic): false alarms per
# hour of collision-free time, extrapolated from the score's excursions on the validation logs
# (twincd.calibration.threshold.threshold_from_parts; studies/real_arm_statistics.py)
DEFAULT_FALSE_ALARMS_PER_HOUR = 1.0
DEFAULT_REPEATS = 5  # the paper's Table II: deep methods as mean ± std over five runs

# `twincd synth`: a path longer than this is joined from segments of at most this length, each
# home → teaching points → home at rest at both ends (a path over a few minutes never stays
# within the flange's radius as one spline)
SYNTH_SEGMENT_S = 35.0

# Events (twincd.detection.events.EventRules): one push, one event. An open event ends when the
# score falls below μ + release × (threshold − μ); an event opening within the merge gap of the
# previous one's end continues it. Chosen in studies/choose_events.py on the real arm's six
# rotations and synth seeds 2 (100 Hz) and 3 (1 kHz), identified-whitened: found pushes and delay
# do not depend on them (flags do); false alarms 2 / 4 / 14 against 2 / 6 / 15 as runs of flags,
# events per found push 0.97 / 0.98 / 0.93; a merge gap of 500 ms+ starts joining separate
# presses at 1 kHz. Persistence (50 ms) cut false alarms at 1 kHz only (15 → 9) and added 50 ms
# of delay on the real arm (70 → 120 ms median): not used.
DEFAULT_EVENT_RELEASE = 0.5
DEFAULT_EVENT_MERGE_MS = 300.0
