"""The diagnosis' least squares (diagnosis.fit.solve): the base block factored once and each hypothesis
fitted beside it (Frisch–Waugh–Lovell) against the whole stacked system solved at once."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qomni.diagnosis.fit import _BaseBlock, _solve_beside


def _whole(columns: np.ndarray, E: np.ndarray, b: np.ndarray):
    """The whole system by numpy's lstsq on unit-norm columns, θ's covariance from the pseudo-inverse."""
    A = np.hstack([columns, E])
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    x, *_ = np.linalg.lstsq(As, b, rcond=None)
    r = b - As @ x
    k = columns.shape[1]
    cov = np.linalg.pinv(As.T @ As)[k:, k:] / np.outer(scale[k:], scale[k:])
    return x / scale, float(r @ r), cov


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 12), q=st.integers(1, 4),
       magnitudes=st.lists(st.floats(-6, 6), min_size=16, max_size=16))
def test_fitting_beside_the_factored_base_block_is_the_whole_least_squares(seed, k, q, magnitudes):
    rng = np.random.default_rng(seed)
    n = 200
    columns = rng.normal(size=(n, k)) * 10.0 ** np.array(magnitudes[:k])     # columns of very different size
    E = rng.normal(size=(n, q)) * 10.0 ** np.array(magnitudes[12:12 + q])
    E[:, 0] += columns[:, 0] * 0.5 * 10.0 ** (magnitudes[12] - magnitudes[0])   # partly collinear with the base
    b = rng.normal(size=n) + columns @ (rng.normal(size=k) / 10.0 ** np.array(magnitudes[:k]))
    block = _BaseBlock.factored([0], [], np.zeros(1, dtype=int), columns, np.zeros(0))
    assert block.q_factor is not None
    x, rss, cov_s, scale_e = _solve_beside(block, E, b)
    cov = cov_s / np.outer(scale_e, scale_e)
    want_x, want_rss, want_cov = _whole(columns, E, b)
    np.testing.assert_allclose(rss, want_rss, rtol=1e-8)
    np.testing.assert_allclose(x[k:], want_x[k:], rtol=1e-6, atol=1e-9 * np.abs(want_x[k:]).max())
    norms = np.linalg.norm(columns, axis=0)                                  # the base part, in b's units
    np.testing.assert_allclose(x[:k] * norms, want_x[:k] * norms, rtol=1e-6, atol=1e-9 * np.abs(b).max())
    np.testing.assert_allclose(cov, want_cov, rtol=1e-6, atol=1e-9 * np.abs(want_cov).max())
    x0, rss0, _, _ = _solve_beside(block, None, b)                          # the base fit alone
    scale = np.linalg.norm(columns, axis=0)
    want0 = np.linalg.lstsq(columns / scale, b, rcond=None)[0] / scale
    np.testing.assert_allclose(x0, want0, rtol=1e-6, atol=1e-9 * np.abs(want0).max())
    np.testing.assert_allclose(rss0, float(np.sum((b - columns @ want0) ** 2)), rtol=1e-8)


def test_a_hypothesis_in_the_span_of_the_base_columns_is_solved_as_one_system():
    """A column the base block already holds leaves nothing beside it: the whole system's minimum-norm
    solution, as numpy's lstsq gives it, not a fit to rounding."""
    rng = np.random.default_rng(3)
    columns = rng.normal(size=(100, 3))
    E = columns[:, :1] * 2.0 + columns[:, 1:2]
    b = rng.normal(size=100)
    block = _BaseBlock.factored([0], [], np.zeros(1, dtype=int), columns, np.zeros(0))
    x, rss, cov_s, scale_e = _solve_beside(block, E, b)
    want_x, want_rss, want_cov = _whole(columns, E, b)
    np.testing.assert_allclose(x, want_x, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(rss, want_rss, rtol=1e-10)
    np.testing.assert_allclose(cov_s / np.outer(scale_e, scale_e), want_cov, rtol=1e-8, atol=1e-12)


def test_a_rank_deficient_base_block_is_solved_as_one_system():
    rng = np.random.default_rng(4)
    columns = rng.normal(size=(100, 3))
    columns[:, 2] = columns[:, 0] - columns[:, 1]
    E = rng.normal(size=(100, 1))
    b = rng.normal(size=100)
    block = _BaseBlock.factored([0], [], np.zeros(1, dtype=int), columns, np.zeros(0))
    assert block.q_factor is None
    x, rss, _, _ = _solve_beside(block, E, b)
    want_x, want_rss, _ = _whole(columns, E, b)
    np.testing.assert_allclose(x, want_x, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(rss, want_rss, rtol=1e-10)


def test_fewer_rows_than_base_columns_are_solved_as_one_system():
    rng = np.random.default_rng(5)
    columns, E, b = rng.normal(size=(4, 6)), rng.normal(size=(4, 1)), rng.normal(size=4)
    block = _BaseBlock.factored([0], [], np.zeros(1, dtype=int), columns, np.zeros(0))
    assert block.q_factor is None
    x, rss, _, _ = _solve_beside(block, E, b)
    want_x, want_rss, _ = _whole(columns, E, b)
    np.testing.assert_allclose(x, want_x, rtol=1e-8, atol=1e-12)
    assert rss == pytest.approx(want_rss, abs=1e-20)
