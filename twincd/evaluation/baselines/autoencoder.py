"""Autoencoder baselines (paper IV-B 4 and 7) on min–max normalised τ_ext, and the PyTorch
helpers the deep baselines share.

- ``point-ae``: 7 → 5 → 3 → 5 → 7 per sample, batch 1000;
- ``window-ae``: 112 → 32 → 11 → 32 → 112 per 16-sample window (Park et al.), batch 128;

both with ReLU and dropout 0.1 after every middle layer, a linear output, mean-squared
reconstruction loss, Adam with lr 1e-4. Score = squared reconstruction error ‖x − AE(x)‖² of the
normalised input (dropout off).

PyTorch is an optional extra (``pip install 'twincd[baselines]'``) imported only inside these
methods; without it ``check()`` raises MethodSkipped. Training runs on the CPU with
``TORCH_THREADS`` (1) thread, inside ``torch.random.fork_rng`` seeded with ``seed`` (weights,
shuffling and dropout), so a seed gives the same model and the caller's RNG state is untouched.

Default epochs (``default_epochs``: point-ae 400, window-ae 800) were chosen on the shipped
sample logs' train and val logs only, never test: the mean validation reconstruction error per
epoch count (seeds 0 and 1) was, for point-ae, 0.59 (200 epochs), 0.48 (400), 0.45 (800) and
0.45 (1600); for window-ae 1.7 (400), 1.07 (800), 0.85 (1600). Point-ae stops within 7 % of its
plateau; window-ae still improves slowly after 800 epochs, and 800 is what the budget allows:
five seeds of all three deep methods plus the other methods in about six minutes of
``evaluate --methods all --repeats 5`` on the 2-core development machine (point-ae ≈ 20 s,
window-ae ≈ 15 s per seed there). Pass ``epochs`` to train longer.

Long training logs: at most ``max_train`` rows (``DEFAULT_MAX_TRAIN_UNITS``, 200 000 samples or
windows) train the network, a seeded uniform random subsample (``subsample_seed``, 0, the same
for every ``seed``) when there are more; the min–max range still comes from every row, and
``note`` says so.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np

from twincd.errors import NotFittedError
from twincd.evaluation.baselines.mob import DEFAULT_GAIN, MobFeatureMethod
from twincd.evaluation.baselines.windows import (
    DEFAULT_MAX_TRAIN_UNITS,
    DEFAULT_SUBSAMPLE_SEED,
    WINDOW_SIZE,
)
from twincd.evaluation.methods import MethodSkipped
from twincd.prepare.prepared import PreparedLog
from twincd.signal.filters import LowPass
from twincd.types import FloatArray

NEEDS_TORCH = "needs PyTorch: pip install 'twincd[baselines]'"
# One thread: on a shared 2-core machine, 2 torch threads made these small models 10–25× slower
# (thread contention); one thread per process leaves room for running methods side by side.
TORCH_THREADS = 1
DEFAULT_LR = 1e-4


def import_torch() -> Any:
    """The torch module, with its CPU thread count set; MethodSkipped when not installed."""
    try:
        import torch
    except ImportError as exc:
        raise MethodSkipped(NEEDS_TORCH) from exc
    threads = max(1, min(TORCH_THREADS, os.cpu_count() or 1))
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    return torch


def mlp_autoencoder(torch: Any, sizes: Sequence[int], dropout: float) -> Any:
    """Linear layers through ``sizes`` (input … output); ReLU + dropout after each middle one."""
    nn = torch.nn
    layers: list[Any] = []
    for i, (a, b) in enumerate(itertools.pairwise(sizes)):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers += [nn.ReLU(), nn.Dropout(dropout)]
    return nn.Sequential(*layers)


def adam(torch: Any, net: Any, lr: float) -> Any:
    """Adam, fused where this torch supports it on the CPU (4× faster for small models)."""
    try:
        return torch.optim.Adam(net.parameters(), lr=lr, fused=True)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.Adam(net.parameters(), lr=lr)


def run_epoch(
    torch: Any, optimiser: Any, tensors: Sequence[Any], loss_fn: Any, batch_size: int
) -> float:
    """One pass over ``tensors`` (same first dimension) in shuffled mini-batches; mean loss.

    ``loss_fn(*batch)`` returns the scalar loss of one batch. Shuffles with the current (forked,
    seeded) torch RNG.
    """
    n = len(tensors[0])
    order = torch.randperm(n)
    shuffled = [t[order] for t in tensors]
    total = 0.0
    for start in range(0, n, batch_size):
        batch = [t[start : start + batch_size] for t in shuffled]
        optimiser.zero_grad()
        loss = loss_fn(*batch)
        loss.backward()
        optimiser.step()
        total += float(loss.detach()) * len(batch[0])
    return total / max(n, 1)


class _Autoencoder(MobFeatureMethod):
    hidden: ClassVar[tuple[int, ...]]
    default_batch: ClassVar[int]
    default_epochs: ClassVar[int]

    def __init__(
        self,
        epochs: int | None = None,
        seed: int = 0,
        batch_size: int | None = None,
        lr: float = DEFAULT_LR,
        dropout: float = 0.1,
        gain: float = DEFAULT_GAIN,
        lowpass: LowPass | None = None,
        stride: int = WINDOW_SIZE,
        max_train: int | None = DEFAULT_MAX_TRAIN_UNITS,
        subsample_seed: int = DEFAULT_SUBSAMPLE_SEED,
    ) -> None:
        super().__init__(gain=gain, lowpass=lowpass, stride=stride)
        self.max_train = max_train
        self.subsample_seed = subsample_seed
        self.seed = seed
        self.epochs = epochs
        self.batch_size = batch_size
        self.lr = lr
        self.dropout = dropout
        self.net_: Any = None
        self.loss_history_: list[float] = []

    def check(self, logs: Sequence[PreparedLog]) -> None:
        import_torch()
        super().check(logs)

    def _fit_scaled(self, x: FloatArray) -> None:
        torch = import_torch()
        epochs = self.default_epochs if self.epochs is None else self.epochs
        batch = self.default_batch if self.batch_size is None else self.batch_size
        x = self._training_rows(x, self.max_train, self.subsample_seed, "max_train")
        data = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            net = mlp_autoencoder(torch, (x.shape[1], *self.hidden, x.shape[1]), self.dropout)
            optimiser = adam(torch, net, self.lr)

            def loss_fn(xb: Any) -> Any:
                return torch.nn.functional.mse_loss(net(xb), xb)

            net.train()
            self.loss_history_ = [
                run_epoch(torch, optimiser, [data], loss_fn, batch) for _ in range(epochs)
            ]
            net.eval()
        self.net_ = net

    def _score_scaled(self, x: FloatArray) -> FloatArray:
        if self.net_ is None:
            raise NotFittedError(f"{self.name} used before fit()", self.name, "call fit() first")
        torch = import_torch()
        with torch.no_grad():
            data = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
            err = ((self.net_(data) - data) ** 2).sum(dim=1)
        out: FloatArray = err.numpy().astype(np.float64)
        return out


class PointAE(_Autoencoder):
    """Autoencoder 7 → 5 → 3 → 5 → 7 on τ_ext(t) per sample (paper IV-B 4). ``stride`` unused."""

    name = "point-ae"
    unit = "sample"
    window: ClassVar[int] = 1
    hidden = (5, 3, 5)
    default_batch = 1000
    default_epochs = 400


class WindowAE(_Autoencoder):
    """Autoencoder 112 → 32 → 11 → 32 → 112 on 16-sample windows of τ_ext (paper IV-B 7),
    windows every ``stride`` samples as in window-ocsvm."""

    name = "window-ae"
    unit = "window"
    window: ClassVar[int] = WINDOW_SIZE
    hidden = (32, 11, 32)
    default_batch = 128
    default_epochs = 800
