"""The graph's value GP (adaptive_graph.gp_value_estimate, written with numpy and scipy) gives
scikit-learn's GaussianProcessRegressor's numbers to the bit, for the kernel it stands for."""

import numpy as np
import pytest

from pipeline.core.adaptive_graph import GraphParams, gp_value_estimate


def sklearn_estimate(train_xy, train_values, query_xy, p):
    sklearn = pytest.importorskip("sklearn")
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    kernel = ConstantKernel(p.gp_signal_std ** 2, "fixed") * RBF(p.gp_length_scale, "fixed") \
        + WhiteKernel(p.gp_noise, "fixed")
    with sklearn.config_context(assume_finite=True, skip_parameter_validation=True):
        gp = GaussianProcessRegressor(kernel, optimizer=None,
                                      normalize_y=len(train_values) > 1)
        gp.fit(train_xy, train_values)
        return gp.predict(query_xy, return_std=True)


@pytest.mark.parametrize("n", [1, 2, 7, 40])
@pytest.mark.parametrize("params", [GraphParams(),
                                    GraphParams(gp_length_scale=0.4, gp_signal_std=2,
                                                gp_noise=1e-2)])
def test_same_numbers_as_sklearn(n, params):
    rng = np.random.default_rng(n)
    for _ in range(5):
        train = rng.uniform(0, 4, (n, 2))
        values = -rng.exponential(3.0, n)
        query = rng.uniform(0, 4, (12, 3))[:, :2]  # a strided view, as the graph passes
        mean, std = gp_value_estimate(train, values, query, params)
        ref_mean, ref_std = sklearn_estimate(train, values, query, params)
        assert mean.shape == ref_mean.shape and std.shape == ref_std.shape
        assert np.array_equal(mean, ref_mean) and np.array_equal(std, ref_std)


def test_constant_values_same_as_sklearn():
    train = np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 1.0]])
    values = np.full(3, -2.5)
    query = np.array([[0.5, 0.5], [5.0, 5.0]])
    for a, b in zip(gp_value_estimate(train, values, query, GraphParams()),
                    sklearn_estimate(train, values, query, GraphParams()), strict=True):
        assert np.array_equal(a, b)
