"""scikit-learn-style regressor: the Levenberg-Marquardt network of Section 7.2.5.

``LMNetworkRegressor().fit(X, y).predict(X_new)``, with ``get_params``/``set_params`` and
``clone`` from scikit-learn, so it works in ``cross_val_predict`` and pipelines.

fit(X, y):

1. min-max scaling of inputs and output to [0, 1] from (X, y) only: a sample that is not
   passed to ``fit`` (the left-out test sample) never influences the scaling or the weights;
2. for each of ``n_members`` networks: a random split of (X, y) into training and
   validation samples (``validation_fraction``, 0.22 as in the dissertation: 35 + 10 of 45),
   ``n_restarts`` random initialisations trained by LM with early stopping on the
   validation samples (:func:`mbus_framework.analysis.crispness.network.train_lm`), the restart with
   the lowest validation MSE kept;
3. predict averages the members (``n_members=1``: the dissertation's single network).

All randomness comes from ``random_state`` (an int seed, a ``numpy.random.Generator`` or
None), so a fit is reproducible from its seed: the same seed gives the same predictions to
rounding (tested to 1e-9 relative; the last bit is not promised, BLAS kernels may round it
differently from one call to the next).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin

from mbus_framework.analysis.crispness.network import MLP, ACTIVATIONS, MinMaxScaling, Training, split_train_validation, train_lm


class LMNetworkRegressor(RegressorMixin, BaseEstimator):
    """One-output multilayer perceptron trained by Levenberg-Marquardt with early stopping.

    Parameters
    ----------
    hidden_layer_sizes : neurons per hidden layer; (6,) is the dissertation's final network.
    activation : 'tanh' or 'logistic' hidden units (the output is linear).
    n_restarts : random initialisations per member; the best by validation MSE is kept.
    n_members : networks averaged in ``predict``, each on its own train/validation split
        (1: the dissertation's single network; averaging removes the dependence of a single
        early-stopped network on its random split).
    validation_fraction : share of the fit data used for early stopping (0: none, train
        to convergence).
    patience : epochs without a new best validation MSE before training stops (MATLAB's
        ``max_fail``, 6).
    max_epochs : upper limit of LM epochs per training run.
    method : 'lm', 'trf' or 'auto' (see :func:`~mbus_framework.analysis.crispness.network.train_lm`).
    random_state : seed (int), ``numpy.random.Generator`` or None.
    """

    def __init__(
        self,
        hidden_layer_sizes: Sequence[int] = (6,),
        activation: str = "tanh",
        n_restarts: int = 3,
        n_members: int = 5,
        validation_fraction: float = 0.22,
        patience: int = 6,
        max_epochs: int = 1000,
        method: str = "auto",
        random_state=None,
    ):
        self.hidden_layer_sizes = hidden_layer_sizes
        self.activation = activation
        self.n_restarts = n_restarts
        self.n_members = n_members
        self.validation_fraction = validation_fraction
        self.patience = patience
        self.max_epochs = max_epochs
        self.method = method
        self.random_state = random_state

    # -- fitting -----------------------------------------------------------------------------
    def fit(self, X, y):
        """Train the members on (X, y) on one BLAS thread: the networks are tiny, so threads
        only add overhead and oversubscribe the cores a campaign or cross-validation uses."""
        with _one_blas_thread():
            return self._fit(X, y)

    def _fit(self, X, y):
        X, y = self._check_xy(X, y)
        self._check_params(len(y))
        rng = np.random.default_rng(self.random_state)
        self.n_features_in_ = X.shape[1]
        self.x_scaling_ = MinMaxScaling.fit(X)
        self.y_scaling_ = MinMaxScaling.fit(y)
        Z, t = self.x_scaling_.transform(X), self.y_scaling_.transform(y[:, None])[:, 0]
        self.net_ = MLP(X.shape[1], tuple(self.hidden_layer_sizes), self.activation)
        self.members_: list[np.ndarray] = []
        self.trainings_: list[Training] = []
        for _ in range(self.n_members):
            train, val = split_train_validation(len(t), self.validation_fraction, rng)
            best: Training | None = None
            for _ in range(self.n_restarts):
                run = train_lm(
                    self.net_, Z[train], t[train], self.net_.initial_weights(rng),
                    Z[val] if len(val) else None, t[val] if len(val) else None,
                    self.patience, self.max_epochs, self.method,
                )
                if best is None or run.score < best.score:
                    best = run
            self.members_.append(best.weights)
            self.trainings_.append(best)
        return self

    # -- prediction --------------------------------------------------------------------------
    def predict_members(self, X) -> np.ndarray:
        """Each member's prediction, shape (n_members, n_samples), in the units of y."""
        self._check_fitted()
        X = self._check_x(X)
        Z = self.x_scaling_.transform(X)
        with _one_blas_thread():
            out = np.array([self.net_.predict(w, Z) for w in self.members_])
        return self.y_scaling_.inverse(out[..., None])[..., 0]

    def predict(self, X) -> np.ndarray:
        return self.predict_members(X).mean(axis=0)

    def learning_curves(self) -> list[dict[str, list[float]]]:
        """Per member: training and validation MSE per epoch, in squared units of y."""
        self._check_fitted()
        s2 = float(self.y_scaling_.span[0]) ** 2
        return [
            {"train": [m * s2 for m in r.train_mse], "validation": [m * s2 for m in r.val_mse], "best_epoch": r.best_epoch}
            for r in self.trainings_
        ]

    # -- checks ------------------------------------------------------------------------------
    def _check_params(self, n: int) -> None:
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {', '.join(ACTIVATIONS)}, not {self.activation!r}")
        if int(self.n_restarts) < 1 or int(self.n_members) < 1:
            raise ValueError("n_restarts and n_members must be at least 1")
        if not 0 <= float(self.validation_fraction) < 1:
            raise ValueError(f"validation_fraction must be in [0, 1), not {self.validation_fraction}")
        if n < 3:
            raise ValueError(f"a network needs at least 3 samples to fit, got {n}")

    def _check_xy(self, X, y) -> tuple[np.ndarray, np.ndarray]:
        X = np.asarray(X, dtype=float)
        X = X[:, None] if X.ndim == 1 else X
        y = np.asarray(y, dtype=float).ravel()
        if X.ndim != 2 or len(X) != len(y):
            raise ValueError(f"X has {len(X)} rows but y has {len(y)} values")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
            raise ValueError("X and y must be finite (no NaN or inf)")
        return X, y

    def _check_x(self, X) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        X = X[:, None] if X.ndim == 1 else X
        if X.shape[1] != self.n_features_in_:
            raise ValueError(f"X has {X.shape[1]} features, the network was fitted with {self.n_features_in_}")
        return X

    def _check_fitted(self) -> None:
        if not hasattr(self, "members_"):
            from sklearn.exceptions import NotFittedError

            raise NotFittedError("LMNetworkRegressor is not fitted yet: call fit(X, y) first")

    @classmethod
    def from_members(cls, net: MLP, members, x_scaling: MinMaxScaling, y_scaling: MinMaxScaling, **params):
        """A fitted regressor from saved weights and scalings (see ``crispness.model``)."""
        est = cls(hidden_layer_sizes=net.hidden, activation=net.activation, n_members=len(members), **params)
        est.net_, est.x_scaling_, est.y_scaling_ = net, x_scaling, y_scaling
        est.n_features_in_ = net.n_inputs
        est.members_ = [np.asarray(w, dtype=float) for w in members]
        est.trainings_ = []
        return est


def _one_blas_thread():
    """A context with BLAS/OpenMP limited to one thread (threadpoolctl, a scikit-learn
    dependency): these networks are tiny, one thread is fastest."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1)
