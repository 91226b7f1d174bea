"""The seed paper's seven comparison methods (section IV-B, Table II), registered by name.

Targets are strings, so scikit-learn and PyTorch load only when a method is used; the deep
methods (point-ae, lstm-mob, window-ae) need the ``[baselines]`` extra (PyTorch).
"""

from __future__ import annotations

from twincd.methods import register

register("naive-diff", "twincd.baselines.naive:NaiveDiff")
register("naive-mob", "twincd.baselines.mob:NaiveMob")
register("point-ocsvm", "twincd.baselines.ocsvm:PointOcsvm")
register("point-ae", "twincd.baselines.autoencoder:PointAE")
register("lstm-mob", "twincd.baselines.lstm:LstmMob")
register("window-ocsvm", "twincd.baselines.ocsvm:WindowOcsvm")
register("window-ae", "twincd.baselines.autoencoder:WindowAE")
