"""The seed paper's seven comparison methods (section IV-B, Table II).

They are listed by name in ``twincd.evaluation.methods.BUILTIN``, so scikit-learn and PyTorch
load only when a method is used; the deep methods (point-ae, lstm-mob, window-ae) need the
``[baselines]`` extra (PyTorch).
"""
