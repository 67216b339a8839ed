"""The Levenberg-Marquardt network (Section 7.2.5): exact Jacobian, training against known
optima and scikit-learn, early stopping, train-only scaling, reproducibility."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.base import clone
from sklearn.model_selection import LeaveOneOut, cross_val_predict
from sklearn.neural_network import MLPRegressor

from mbus_framework.analysis.crispness.validation import leave_one_out
from mbus_framework.analysis.crispness.network import MLP, MinMaxScaling, split_train_validation, train_lm
from mbus_framework.analysis.crispness.regressor import LMNetworkRegressor


#: a 2-2-1 tanh teacher with moderate weights: its units are not saturated on [0, 1]^2, so the
#: least-squares optimum on noisy data is interior and well defined
TEACHER_LAYERS = [(np.array([[2.0, -1.5], [1.0, 2.5]]), np.array([-0.5, -1.0])), (np.array([[1.5, -1.0]]), np.array([0.3]))]


def teacher_data(n=200, noise=0.0, seed=0):
    """Inputs in [0, 1]^2 and outputs of the teacher network (plus Gaussian noise)."""
    rng = np.random.default_rng(seed)
    net = MLP(2, (2,), "tanh")
    w = net.pack(TEACHER_LAYERS)
    X = rng.random((n, 2))
    return net, w, X, net.predict(w, X) + noise * rng.normal(size=n)


@settings(max_examples=30)
@given(
    n_inputs=st.integers(1, 4),
    hidden=st.lists(st.integers(1, 5), min_size=1, max_size=3),
    activation=st.sampled_from(["tanh", "logistic"]),
    seed=st.integers(0, 2**32 - 1),
)
def test_jacobian_is_exact(n_inputs, hidden, activation, seed):
    rng = np.random.default_rng(seed)
    net = MLP(n_inputs, hidden, activation)
    w, X = rng.normal(0, 1, net.n_weights), rng.random((7, n_inputs))
    J = net.jacobian(w, X)
    h = 1e-6
    fd = np.column_stack([(net.predict(w + h * e, X) - net.predict(w - h * e, X)) / (2 * h) for e in np.eye(net.n_weights)])
    assert J.shape == (7, net.n_weights)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-8)


def test_weights_pack_and_unpack_round_trip():
    net = MLP(3, (4, 2), "tanh")
    w = np.arange(net.n_weights, dtype=float)
    layers = net.layers(w)
    assert [L[0].shape for L in layers] == [(4, 3), (2, 4), (1, 2)]
    np.testing.assert_array_equal(net.pack(layers), w)
    with pytest.raises(ValueError):
        net.layers(w[:-1])


def test_lm_finds_the_known_optimum_of_a_teacher_network():
    """Noise-free data from the teacher: the optimum is the teacher itself (zero loss), up to
    the network's symmetries, so predictions on fresh inputs must agree."""
    net, w_true, X, y = teacher_data(n=60, seed=3)
    rng = np.random.default_rng(1)
    best = min((train_lm(net, X, y, net.initial_weights(rng)) for _ in range(4)), key=lambda r: r.score)
    assert best.score < 1e-20
    X_new = np.random.default_rng(9).random((50, 2))
    np.testing.assert_allclose(net.predict(best.weights, X_new), net.predict(w_true, X_new), atol=1e-8)


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
def test_forward_pass_agrees_with_scikit_learn():
    """Our weights put into scikit-learn's MLPRegressor give the same predictions."""
    net, w, X, y = teacher_data(n=20, seed=2)
    sk = MLPRegressor(hidden_layer_sizes=(2,), activation="tanh", max_iter=1).fit(X, y)  # allocate
    sk.coefs_ = [W.T.copy() for W, _ in net.layers(w)]
    sk.intercepts_ = [b.copy() for _, b in net.layers(w)]
    np.testing.assert_allclose(sk.predict(X), net.predict(w, X), rtol=1e-13, atol=1e-13)


def test_lm_loss_agrees_with_scikit_learn():
    """Same noisy data, same 2-2-1 tanh network, no penalty: the least-squares loss of our LM
    restarts and of scikit-learn's L-BFGS restarts agree, and LM is not worse."""
    net, _, X, y = teacher_data(n=200, noise=0.02, seed=5)
    rng = np.random.default_rng(2)
    ours = min(train_lm(net, X, y, net.initial_weights(rng)).score for _ in range(4))
    theirs = min(
        2 * MLPRegressor(hidden_layer_sizes=(2,), activation="tanh", solver="lbfgs", alpha=0.0, tol=1e-14,
                         max_iter=20000, max_fun=100000, random_state=s).fit(X, y).loss_
        for s in range(2)
    )  # scikit-learn's squared-error loss is MSE / 2
    assert ours == pytest.approx(theirs, rel=1e-4)  # L-BFGS stops on a relative loss change of ~1e-9
    assert ours <= theirs * (1 + 1e-9)


def test_method_lm_and_trf_reach_the_same_optimum():
    net, _, X, y = teacher_data(n=100, noise=0.02, seed=8)
    starts = [net.initial_weights(np.random.default_rng(s)) for s in range(3)]
    lm = min(train_lm(net, X, y, w0, method="lm").score for w0 in starts)
    trf = min(train_lm(net, X, y, w0, method="trf").score for w0 in starts)
    assert lm == pytest.approx(trf, rel=1e-8)


def test_auto_method_trains_more_weights_than_samples():
    """A 4-6-1 network has 37 weights; 20 samples work through the trust-region form."""
    rng = np.random.default_rng(2)
    net, X = MLP(4, (6,), "tanh"), rng.random((20, 4))
    y = np.sin(X @ [1.0, 2.0, -1.0, 0.5])
    run = train_lm(net, X, y, net.initial_weights(rng), max_epochs=200)
    assert np.isfinite(run.score) and run.score < np.var(y)


def test_early_stopping_keeps_the_best_validation_epoch():
    net, _, X, y = teacher_data(n=40, noise=0.3, seed=11)
    net = MLP(2, (8,), "tanh")
    rng = np.random.default_rng(0)
    train, val = split_train_validation(len(y), 0.3, rng)
    run = train_lm(net, X[train], y[train], net.initial_weights(rng), X[val], y[val], patience=4)
    assert run.best_epoch == int(np.argmin(run.val_mse))
    kept = np.mean((net.predict(run.weights, X[val]) - y[val]) ** 2)
    assert kept == pytest.approx(min(run.val_mse), rel=1e-12)
    if "validation" in run.stop:
        assert run.epochs - run.best_epoch == 4


def test_split_follows_the_dissertation_proportions():
    train, val = split_train_validation(45, 0.22, np.random.default_rng(0))
    assert (len(train), len(val)) == (35, 10)
    assert sorted(np.concatenate([train, val])) == list(range(45))


@settings(max_examples=12)
@given(seed=st.integers(0, 2**31), k=st.integers(0, 9), shift=st.floats(-1e6, 1e6, allow_nan=False))
def test_held_out_sample_never_reaches_scaling_or_weights(seed, k, shift):
    """Leave-one-out: altering the held-out sample (inputs and score, even far outside the
    range) changes neither that fold's scaling nor its weights."""
    rng = np.random.default_rng(seed)
    X, y = rng.random((10, 2)) * [3e10, 5e9], rng.random(10) * 9
    est = LMNetworkRegressor(hidden_layer_sizes=(2,), n_restarts=1, n_members=1, max_epochs=30)
    a = leave_one_out(est, X, y, seed=7, keep_models=True).fold_models[k]
    X2, y2 = X.copy(), y.copy()
    X2[k] += shift
    y2[k] -= shift
    b = leave_one_out(est, X2, y2, seed=7, keep_models=True).fold_models[k]
    rest = np.delete(np.arange(10), k)
    np.testing.assert_array_equal(a.x_scaling_.low, X[rest].min(axis=0))
    np.testing.assert_array_equal(a.x_scaling_.high, X[rest].max(axis=0))
    for attr in ("low", "high"):
        np.testing.assert_array_equal(getattr(a.x_scaling_, attr), getattr(b.x_scaling_, attr))
        np.testing.assert_array_equal(getattr(a.y_scaling_, attr), getattr(b.y_scaling_, attr))
    np.testing.assert_allclose(a.members_[0], b.members_[0], rtol=1e-9, atol=1e-12)


def test_scaling_maps_training_data_onto_the_unit_interval():
    X = np.array([[1.0, 5.0, 2.0], [3.0, 5.0, -2.0], [2.0, 5.0, 0.0]])
    s = MinMaxScaling.fit(X)
    Z = s.transform(X)
    np.testing.assert_allclose(Z.min(axis=0), [0, 0, 0])
    np.testing.assert_allclose(Z.max(axis=0), [1, 0, 1])  # a constant column maps to 0
    np.testing.assert_allclose(s.inverse(Z), X)


def test_regressor_is_reproducible_from_its_seed_and_sklearn_compatible():
    rng = np.random.default_rng(4)
    X = rng.random((30, 2))
    y = np.sin(3 * X[:, 0]) + X[:, 1] ** 2 + 0.05 * rng.normal(size=30)
    est = LMNetworkRegressor(hidden_layer_sizes=(3,), n_restarts=2, n_members=2, random_state=5)
    p1 = clone(est).fit(X, y).predict(X)
    p2 = clone(est).fit(X, y).predict(X)
    p3 = clone(est).set_params(random_state=6).fit(X, y).predict(X)
    # the same seed gives the same network to rounding (a BLAS kernel may round the last bit
    # differently from call to call, which early stopping cannot amplify beyond 1e-9)
    np.testing.assert_allclose(p1, p2, rtol=1e-9, atol=0)
    assert np.max(np.abs(p1 - p3)) > 1e-6  # another seed: another network
    assert est.get_params()["hidden_layer_sizes"] == (3,)
    loo = cross_val_predict(est, X, y, cv=LeaveOneOut())
    assert np.corrcoef(loo, y)[0, 1] > 0.8


def test_regressor_predicts_in_the_units_of_y():
    """Scaling is undone: a linear target far from [0, 1] is reproduced."""
    rng = np.random.default_rng(0)
    X = rng.random((40, 2)) * [2e10, 5e3] + [1e10, 1e3]
    y = 3.0 + 2e-10 * X[:, 0] - 1e-4 * X[:, 1]
    est = LMNetworkRegressor((2,), n_restarts=2, n_members=1, validation_fraction=0, random_state=0).fit(X, y)
    np.testing.assert_allclose(est.predict(X), y, atol=1e-4)


def test_regressor_rejects_bad_input():
    est = LMNetworkRegressor((2,), n_restarts=1, n_members=1, random_state=0)
    with pytest.raises(ValueError, match="rows"):
        est.fit(np.zeros((5, 2)), np.zeros(4))
    with pytest.raises(ValueError, match="finite"):
        est.fit(np.full((5, 2), np.nan), np.zeros(5))
    with pytest.raises(ValueError, match="activation"):
        LMNetworkRegressor(activation="relu").fit(np.random.rand(6, 2), np.random.rand(6))
    est.fit(np.random.rand(8, 2), np.random.rand(8))
    with pytest.raises(ValueError, match="features"):
        est.predict(np.zeros((3, 3)))
