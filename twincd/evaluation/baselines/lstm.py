"""LSTM MOB (Lim et al. 2021; paper IV-B 5): an LSTM trained on collision-free logs to output the
momentum observer's τ_ext(t) from q(t), q̇(t) and q̇(t−1); score(t) = ‖τ_ext,MOB(t) − LSTM(t)‖²
in N·m² (what the observer reports that the learned model-error does not explain).

Hyper-parameters as the paper: sequences of 100 samples, one LSTM layer of 100 units and a linear
output layer, batch 1000 sequences, dropout 0, Adam, lr 1e-4; inputs and targets min–max
normalised on the training data (eq. 8); q̇ low-pass filtered like the efforts.

Choices the paper leaves open (documented, chosen for a CPU budget):

- sequence-to-sequence: the LSTM reads a log in consecutive sequences of ``seq_len`` samples
  and outputs τ_ext at every step; the loss is the mean squared error over all steps. Each epoch
  cuts every training log at a fresh random phase, so all positions are seen. Scoring cuts the
  log from its first sample the same way (the last, shorter sequence is read on its own).
- the output layer's bias starts at the mean normalised training target, so an untrained
  model predicts the mean τ_ext instead of an arbitrary offset.
- default epochs (``DEFAULT_EPOCHS`` = 60), chosen on the sample logs' train and val logs only:
  one forward/backward pass of a 1000 × 100 batch takes over a second on one CPU core, so at
  lr 1e-4 the LSTM is compute-starved. Mean validation score (seeds 0, 1): 3.15 after 10
  epochs, 3.07 after 30, 2.95 after 60 (about 25 s per seed on the 2-core development
  machine), still falling slowly. The paper trained for 747 s on a V100. Pass ``epochs`` (and,
  as a deliberate deviation, ``lr``) to train longer.
- long training logs: at most ``max_train`` samples (``DEFAULT_MAX_TRAIN_UNITS``, 200 000)
  train the LSTM, as a seeded random choice (``subsample_seed``, 0, the same for every ``seed``)
  of ``PIECE_SEQUENCES`` × ``seq_len``-sample stretches of the training logs, each read as a log
  of its own; the min–max ranges still come from every sample, and ``note`` says so.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from twincd.errors import DataError, NotFittedError
from twincd.evaluation.baselines.autoencoder import DEFAULT_LR, adam, import_torch, run_epoch
from twincd.evaluation.baselines.mob import (
    DEFAULT_GAIN,
    check_mob,
    filtered_velocity,
    mob_features,
)
from twincd.evaluation.baselines.windows import (
    DEFAULT_MAX_TRAIN_UNITS,
    DEFAULT_SUBSAMPLE_SEED,
    MinMaxScaler,
    subsample,
)
from twincd.evaluation.methods import MethodSkipped, ScoringMethod
from twincd.prepare.prepared import PreparedLog
from twincd.signal.filters import LowPass
from twincd.types import FloatArray

DEFAULT_EPOCHS = 60
SEQ_LEN = 100
HIDDEN = 100
PIECE_SEQUENCES = 10  # sequences per stretch of a capped training set


def training_pieces(
    lengths: Sequence[int], cap: int | None, piece: int, seed: int
) -> list[tuple[int, int, int]] | None:
    """(log, start, stop) of a seeded random choice of ``piece``-sample stretches of logs of
    ``lengths`` holding about ``cap`` samples, in order; None when every sample fits."""
    if cap is None or sum(lengths) <= cap:
        return None
    pieces = [(i, a, min(a + piece, n)) for i, n in enumerate(lengths) for a in range(0, n, piece)]
    keep = subsample(len(pieces), max(1, cap // piece), seed)
    return None if keep is None else [pieces[k] for k in keep.tolist()]


class LstmMob(ScoringMethod):
    """LSTM MOB (paper IV-B 5); see the module docstring."""

    name = "lstm-mob"
    unit = "sample"
    learns = True

    def __init__(
        self,
        epochs: int = DEFAULT_EPOCHS,
        seed: int = 0,
        seq_len: int = SEQ_LEN,
        hidden: int = HIDDEN,
        batch_size: int = 1000,
        lr: float = DEFAULT_LR,
        dropout: float = 0.0,
        gain: float = DEFAULT_GAIN,
        lowpass: LowPass | None = None,
        max_train: int | None = DEFAULT_MAX_TRAIN_UNITS,
        subsample_seed: int = DEFAULT_SUBSAMPLE_SEED,
    ) -> None:
        self.max_train = max_train
        self.subsample_seed = subsample_seed
        self.epochs = epochs
        self.seed = seed
        self.seq_len = seq_len
        self.hidden = hidden
        self.batch_size = batch_size
        self.lr = lr
        self.dropout = dropout
        self.gain = gain
        self.lowpass = lowpass
        self.note: str | None = None
        self.joint_names_: tuple[str, ...] | None = None
        self.in_scaler_: MinMaxScaler | None = None
        self.out_scaler_: MinMaxScaler | None = None
        self.net_: Any = None
        self.loss_history_: list[float] = []

    def check(self, logs: Sequence[PreparedLog]) -> None:
        import_torch()
        check_mob(logs)

    def inputs(self, log: PreparedLog, joint_names: Sequence[str]) -> FloatArray:
        """[q(t), q̇(t), q̇(t−1)] per sample, (N, 3 × joints); q̇(−1) = q̇(0)."""
        if sorted(joint_names) != sorted(log.joint_names):
            raise MethodSkipped(
                f"{log.source} has joints {', '.join(log.joint_names)}, the method was trained "
                f"on {', '.join(joint_names)}"
            )
        cols = [log.joint_names.index(n) for n in joint_names]
        q = log.states.position[:, cols]
        qd = filtered_velocity(log, self.lowpass or log.lowpass)[:, cols]
        prev = np.concatenate([qd[:1], qd[:-1]])
        return np.concatenate([q, qd, prev], axis=1)

    def fit(self, train: Sequence[PreparedLog]) -> LstmMob:
        if not train:
            raise DataError(
                "lstm-mob needs training logs",
                "training logs",
                "give collision-free training logs",
                option="train",
            )
        self.check(train)
        torch = import_torch()
        names = train[0].joint_names
        xs = [self.inputs(log, names) for log in train]
        ys = [mob_features(log, names, self.gain, self.lowpass) for log in train]
        lengths = np.array([len(x) for x in xs])
        if lengths.max() < 2:
            raise DataError(
                "the training logs are too short for lstm-mob",
                "training logs",
                "give longer logs",
                option="train",
            )
        in_scaler = MinMaxScaler().fit(np.concatenate(xs))
        out_scaler = MinMaxScaler().fit(np.concatenate(ys))
        self.note = None
        piece = PIECE_SEQUENCES * self.seq_len
        pieces = training_pieces(lengths.tolist(), self.max_train, piece, self.subsample_seed)
        if pieces is not None:
            total = int(lengths.sum())
            xs = [xs[i][a:b] for i, a, b in pieces]
            ys = [ys[i][a:b] for i, a, b in pieces]
            lengths = np.array([len(x) for x in xs])
            self.note = (
                f"trained on a random {int(lengths.sum())} of {total} training samples "
                f"(max_train, subsample_seed {self.subsample_seed})"
            )
        x_all = torch.from_numpy(
            np.ascontiguousarray(in_scaler.transform(np.concatenate(xs)), dtype=np.float32)
        )
        y_all = torch.from_numpy(
            np.ascontiguousarray(out_scaler.transform(np.concatenate(ys)), dtype=np.float32)
        )
        offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        seq = int(min(self.seq_len, lengths.max()))
        rng = np.random.default_rng(self.seed)

        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            net = _LstmRegressor(torch, x_all.shape[1], self.hidden, y_all.shape[1], self.dropout)
            with torch.no_grad():
                net.out.bias.copy_(y_all.mean(dim=0))
            optimiser = adam(torch, net, self.lr)
            index = torch.arange(seq)

            def loss_fn(xb: Any, yb: Any) -> Any:
                return torch.nn.functional.mse_loss(net(xb), yb)

            history: list[float] = []
            net.train()
            for _ in range(self.epochs):
                # fresh random phase per epoch: whole sequences of every log
                starts = []
                for off, n in zip(offsets, lengths):
                    phase = int(rng.integers(0, min(seq, n - seq + 1))) if n >= seq else 0
                    starts.append(off + np.arange(phase, n - seq + 1, seq))
                start_t = torch.from_numpy(np.concatenate(starts).astype(np.int64))
                rows = start_t[:, None] + index[None, :]
                history.append(
                    run_epoch(
                        torch, optimiser, [x_all[rows], y_all[rows]], loss_fn, self.batch_size
                    )
                )
            net.eval()
        self.loss_history_ = history
        self.net_ = net
        self.joint_names_ = names
        self.in_scaler_ = in_scaler
        self.out_scaler_ = out_scaler
        return self

    def predict(self, log: PreparedLog) -> FloatArray:
        """The LSTM's τ_ext(t) in N·m, (N, joints) in the fitted joint order."""
        if self.net_ is None or self.in_scaler_ is None or self.out_scaler_ is None:
            raise NotFittedError("lstm-mob used before fit()", self.name, "call fit() first")
        assert self.joint_names_ is not None
        torch = import_torch()
        x = self.in_scaler_.transform(self.inputs(log, self.joint_names_))
        n, seq = len(x), self.seq_len
        full = (n // seq) * seq
        out = np.empty((n, len(self.joint_names_)))
        with torch.no_grad():
            if full:
                xb = torch.from_numpy(np.ascontiguousarray(x[:full], dtype=np.float32))
                pred = self.net_(xb.reshape(full // seq, seq, x.shape[1]))
                out[:full] = pred.reshape(full, -1).numpy()
            if full < n:
                xb = torch.from_numpy(np.ascontiguousarray(x[full:], dtype=np.float32))
                out[full:] = self.net_(xb[None])[0].numpy()
        return self.out_scaler_.inverse_transform(out)

    def score(self, log: PreparedLog) -> FloatArray:
        pred = self.predict(log)
        assert self.joint_names_ is not None
        diff = mob_features(log, self.joint_names_, self.gain, self.lowpass) - pred
        out: FloatArray = np.einsum("ij,ij->i", diff, diff)
        return out


def _LstmRegressor(torch: Any, n_in: int, hidden: int, n_out: int, dropout: float) -> Any:
    """nn.Module: LSTM(n_in → hidden) then Linear(hidden → n_out) at every step."""
    nn = torch.nn
    module: Any = nn.Module

    class LstmRegressor(module):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__()
            self.lstm = nn.LSTM(n_in, hidden, batch_first=True)
            self.drop = nn.Dropout(dropout)
            self.out = nn.Linear(hidden, n_out)

        def forward(self, x: Any) -> Any:
            h, _ = self.lstm(x)
            return self.out(self.drop(h))

    return LstmRegressor()
