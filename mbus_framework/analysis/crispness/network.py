"""Multilayer perceptron trained by Levenberg-Marquardt with early stopping (Section 7.2.5).

The network maps scaled inputs x in [0, 1]^d to one scaled output:

    a_0 = x,   a_l = phi(W_l a_{l-1} + b_l)  (l = 1..L hidden layers),   y = w_o . a_L + b_o

with phi = tanh or the logistic function and a linear output. The weights are fitted by
nonlinear least squares on the training residuals r_i(w) = y(x_i; w) - t_i, with the exact
Jacobian dr/dw from back-propagation, by ``scipy.optimize.least_squares``: ``method='lm'``
(MINPACK's Levenberg-Marquardt, for at least as many training samples as weights) or
``'trf'`` (its trust-region form, which also handles fewer samples than weights). As in
MATLAB's ``trainlm`` one *epoch* is one accepted LM step (one Jacobian evaluation); after each
epoch the validation MSE is measured, and training stops after ``patience`` epochs without a
new best validation MSE, returning the weights of the best epoch (early stopping).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.optimize import least_squares
from scipy.special import expit

#: hidden activation -> (phi(z), phi'(z) written with a = phi(z))
ACTIVATIONS = {
    "tanh": (np.tanh, lambda a: 1.0 - a * a),
    "logistic": (expit, lambda a: a * (1.0 - a)),
}


class MLP:
    """Architecture and arithmetic of a fully connected network with one linear output.

    Weights are one flat vector: per layer (hidden layers, then the output) the matrix
    W (n_out x n_in, row-major) followed by the biases b (n_out).
    """

    def __init__(self, n_inputs: int, hidden: Sequence[int] = (6,), activation: str = "tanh"):
        if activation not in ACTIVATIONS:
            raise ValueError(f"unknown activation {activation!r}; choose one of: {', '.join(ACTIVATIONS)}")
        if n_inputs < 1 or any(int(h) < 1 for h in hidden):
            raise ValueError("a network needs at least one input and one neuron per hidden layer")
        self.n_inputs = int(n_inputs)
        self.hidden = tuple(int(h) for h in hidden)
        self.activation = activation
        self._phi, self._dphi = ACTIVATIONS[activation]
        sizes = (self.n_inputs, *self.hidden, 1)
        self.shapes = [(sizes[i + 1], sizes[i]) for i in range(len(sizes) - 1)]

    def __repr__(self) -> str:
        return f"MLP({self.n_inputs}-{'-'.join(map(str, self.hidden))}-1, {self.activation})"

    @property
    def n_weights(self) -> int:
        return sum(o * i + o for o, i in self.shapes)

    def layers(self, w: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Split the flat weight vector into [(W_1, b_1), ..., (W_o, b_o)] (views)."""
        w = np.asarray(w, dtype=float)
        if w.shape != (self.n_weights,):
            raise ValueError(f"{self!r} has {self.n_weights} weights, got an array of shape {w.shape}")
        out, k = [], 0
        for o, i in self.shapes:
            W = w[k : k + o * i].reshape(o, i)
            k += o * i
            out.append((W, w[k : k + o]))
            k += o
        return out

    def pack(self, layers: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """Inverse of :meth:`layers`."""
        parts = []
        for (W, b), (o, i) in zip(layers, self.shapes, strict=True):
            W, b = np.asarray(W, dtype=float), np.asarray(b, dtype=float)
            if W.shape != (o, i) or b.shape != (o,):
                raise ValueError(f"layer shapes {W.shape}, {b.shape} do not fit {self!r}")
            parts += [W.ravel(), b]
        return np.concatenate(parts)

    def _activations(self, w: np.ndarray, X: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        layers = self.layers(w)
        acts = [np.asarray(X, dtype=float)]
        for W, b in layers[:-1]:
            acts.append(self._phi(acts[-1] @ W.T + b))
        Wo, bo = layers[-1]
        return acts, (acts[-1] @ Wo.T + bo)[:, 0]

    def predict(self, w: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Network output y(x; w) for the rows of X (n x n_inputs) -> (n,)."""
        return self._activations(w, X)[1]

    def jacobian(self, w: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Exact dy_i/dw (n x n_weights) by back-propagation, one sample per row."""
        layers = self.layers(w)
        acts, _ = self._activations(w, X)
        n = acts[0].shape[0]
        blocks: list[np.ndarray] = []
        g = np.ones((n, 1))  # dy / d(pre-activation) of the current layer
        for depth in range(len(layers) - 1, -1, -1):
            a_in = acts[depth]
            blocks.append(g)  # d/db
            blocks.append((g[:, :, None] * a_in[:, None, :]).reshape(n, -1))  # d/dW
            if depth:
                W = layers[depth][0]
                g = (g @ W) * self._dphi(acts[depth])
        return np.concatenate(blocks[::-1], axis=1)

    def initial_weights(self, rng: np.random.Generator) -> np.ndarray:
        """scikit-learn's (Glorot) initialisation: U(-s, s), s = sqrt(f / (fan_in + fan_out)),
        f = 6 for tanh and 2 for the logistic function, for weights and biases alike."""
        factor = 2.0 if self.activation == "logistic" else 6.0
        parts = []
        for o, i in self.shapes:
            s = np.sqrt(factor / (i + o))
            parts += [rng.uniform(-s, s, o * i), rng.uniform(-s, s, o)]
        return np.concatenate(parts)


@dataclass(frozen=True)
class MinMaxScaling:
    """Affine map of each column onto [0, 1]: z = (x - low) / (high - low).

    Fitted on training data only; a constant column maps to 0 (span taken as 1).
    """

    low: np.ndarray
    high: np.ndarray

    @classmethod
    def fit(cls, X: np.ndarray) -> "MinMaxScaling":
        X = np.asarray(X, dtype=float)
        X = X[:, None] if X.ndim == 1 else X
        return cls(X.min(axis=0), X.max(axis=0))

    @property
    def span(self) -> np.ndarray:
        span = np.asarray(self.high, dtype=float) - np.asarray(self.low, dtype=float)
        return np.where(span > 0, span, 1.0)

    def transform(self, X: np.ndarray) -> np.ndarray:
        return (np.asarray(X, dtype=float) - self.low) / self.span

    def inverse(self, Z: np.ndarray) -> np.ndarray:
        return np.asarray(Z, dtype=float) * self.span + self.low


@dataclass
class Training:
    """One LM training run: the kept weights and the learning curves (scaled units)."""

    weights: np.ndarray
    train_mse: list[float] = field(default_factory=list)  # per epoch, epoch 0 = start
    val_mse: list[float] = field(default_factory=list)  # empty without validation data
    best_epoch: int = 0
    stop: str = ""

    @property
    def epochs(self) -> int:
        return len(self.train_mse) - 1

    @property
    def score(self) -> float:
        """Selection criterion of restarts: validation MSE at the kept epoch, else training MSE."""
        curve = self.val_mse if self.val_mse else self.train_mse
        return float(curve[self.best_epoch])


class _EarlyStop(Exception):
    pass


def train_lm(
    net: MLP,
    X: np.ndarray,
    y: np.ndarray,
    w0: np.ndarray,
    X_val: np.ndarray | None = None,
    y_val: np.ndarray | None = None,
    patience: int = 6,
    max_epochs: int = 1000,
    method: str = "auto",
    tol: float = 1e-12,
) -> Training:
    """Fit the weights to (X, y) by Levenberg-Marquardt from ``w0`` (all arrays scaled).

    With validation data, stops after ``patience`` epochs without a new best validation MSE
    and keeps the best epoch's weights; without, runs to convergence (``tol`` on cost,
    step and gradient) or ``max_epochs``. ``method``: 'lm', 'trf' or 'auto' ('lm' when
    there are at least as many training samples as weights, else 'trf').
    """
    X, y = np.asarray(X, dtype=float), np.asarray(y, dtype=float)
    if method == "auto":
        method = "lm" if len(y) >= net.n_weights else "trf"
    if method not in ("lm", "trf"):
        raise ValueError(f"method must be 'lm', 'trf' or 'auto', not {method!r}")
    validate = X_val is not None and y_val is not None and len(y_val) > 0
    run = Training(np.array(w0, dtype=float))
    best = {"w": run.weights, "score": np.inf}

    def residuals(w):
        return net.predict(w, X) - y

    def jacobian(w):  # called once per accepted step: one epoch
        train = float(np.mean(residuals(w) ** 2))
        run.train_mse.append(train)
        score = train
        if validate:
            score = float(np.mean((net.predict(w, X_val) - y_val) ** 2))
            run.val_mse.append(score)
        epoch = len(run.train_mse) - 1
        if score < best["score"]:
            best.update(w=np.array(w, dtype=float), score=score)
            run.best_epoch = epoch
        if validate and epoch - run.best_epoch >= patience:
            run.stop = f"validation MSE not improved for {patience} epochs"
            raise _EarlyStop
        if epoch >= max_epochs:
            run.stop = f"maximum of {max_epochs} epochs"
            raise _EarlyStop
        return net.jacobian(w, X)

    try:
        res = least_squares(
            residuals, run.weights, jac=jacobian, method=method, ftol=tol, xtol=tol, gtol=tol,
            max_nfev=50 * max_epochs,
        )
        run.stop = res.message
        final = np.asarray(res.x, dtype=float)
        # the accepted end point may not have had its own epoch record yet
        if not np.array_equal(final, best["w"]):
            _record_end_point(net, final, X, y, X_val if validate else None, y_val, run, best)
    except _EarlyStop:
        pass
    run.weights = best["w"]
    return run


def _record_end_point(net, w, X, y, X_val, y_val, run: Training, best: dict) -> None:
    """Record the solver's final point as one more epoch (no Jacobian needed)."""
    train = float(np.mean((net.predict(w, X) - y) ** 2))
    run.train_mse.append(train)
    score = train
    if X_val is not None:
        score = float(np.mean((net.predict(w, X_val) - y_val) ** 2))
        run.val_mse.append(score)
    if score < best["score"]:
        best.update(w=np.array(w, dtype=float), score=score)
        run.best_epoch = len(run.train_mse) - 1


def split_train_validation(n: int, validation_fraction: float, rng: np.random.Generator):
    """Random split of range(n) into (train, validation) index arrays; the validation part
    has round(fraction n) samples (10 of 45 for the dissertation's 0.22), at least one
    training sample is always kept."""
    n_val = int(round(validation_fraction * n)) if validation_fraction > 0 else 0
    n_val = min(max(n_val, 1 if validation_fraction > 0 else 0), n - 1)
    order = rng.permutation(n)
    return np.sort(order[n_val:]), np.sort(order[:n_val])
