"""The estimators, the block bootstrap and the identifiability report on synthetic rows of (19)
(test_estimation.synthetic_blocks: the paper's structure, white noise per channel)."""
import numpy as np
import pytest

from qomni.conventions import P1_NAMES
from qomni.ident.estimation import estimate
from qomni.ident.regressor import RegressorBlock
from test_estimation import P_TRUE, synthetic_blocks


def test_consistent_equals_wls_when_wls_is_admissible():
    blocks = synthetic_blocks(seed=3)
    wls = estimate(blocks, B_w=P_TRUE[-1], estimator="wls")
    con = estimate(blocks, B_w=P_TRUE[-1], estimator="consistent")
    assert np.array_equal(wls.p1, con.p1) and con.estimator_info["active_bounds"] == []


def test_consistent_keeps_every_parameter_admissible():
    p = P_TRUE.copy()
    p[P1_NAMES.index("C_r")] = 0.0                         # a steering unit of negligible inertia
    for seed in range(40):
        blocks = synthetic_blocks(p=p, seed=seed, noise_scale=20.0)
        wls = estimate(blocks, B_w=p[-1])
        if wls.values["C_r"] < 0:
            break
    else:
        pytest.fail("no seed gave an inadmissible WLS estimate")
    con = estimate(blocks, B_w=p[-1], estimator="consistent")
    assert np.all(con.p1 >= 0) and con.values["C_r"] == 0.0
    assert con.estimator_info["active_bounds"] == ["C_r"] and con.std["C_r"] == 0.0
    cost = lambda r: sum(np.sum(((b.tau - b.Theta @ r.p) / r.channel_sigma[b.channel[0]]) ** 2)  # noqa: E731
                         for b in blocks)
    assert cost(con) >= cost(wls)


def test_irls_rejects_gross_outlier_rows():
    rng = np.random.default_rng(7)
    blocks = []
    for b in synthetic_blocks(seed=1):
        tau = b.tau.copy()
        rows = rng.choice(b.n_rows, size=b.n_rows // 100, replace=False)
        tau[rows] += 50 * np.std(tau)                      # one-signed glitches: they bias LS
        blocks.append(RegressorBlock(b.Theta, tau, b.velocity, b.channel))
    sigma = estimate(synthetic_blocks(seed=1), B_w=P_TRUE[-1]).std_vector     # σ without outliers
    z = lambda r: np.max(np.abs(r.p1 - P_TRUE[:-1]) / sigma)  # noqa: E731
    wls = estimate(blocks, B_w=P_TRUE[-1])
    irls = estimate(blocks, B_w=P_TRUE[-1], estimator="irls")
    assert z(wls) > 10 and z(irls) < 4
    used = sum(irls.rows_used.values())                    # the glitches among the moving rows
    assert irls.estimator_info["converged"] and 0.005 * used < irls.estimator_info["rows_rejected"] < 0.02 * used


def test_bootstrap_std_agrees_with_the_least_squares_std_on_white_noise():
    res = estimate(synthetic_blocks(seed=2), B_w=P_TRUE[-1])
    ratio = np.array([res.std_bootstrap[n] / res.std[n] for n in P1_NAMES])
    assert np.all((ratio > 0.6) & (ratio < 1.6)), dict(zip(P1_NAMES, ratio.round(2)))


def test_identifiability_report_names_the_determining_step():
    res = estimate(synthetic_blocks(seed=2), B_w=P_TRUE[-1])
    rep = res.identifiability
    for n in ("C_l", "d_vl", "d_cl"):
        assert rep[n]["determined_by"] == ["steer_left"]
    for n in ("C_r", "d_vr", "d_cr"):
        assert rep[n]["determined_by"] == ["steer_right"]
    assert rep["m_ch"]["determined_by"] == ["straight"]
    assert "rotation" in rep["C_ch"]["determined_by"]
    assert rep["m_ch"]["relative_std"] == pytest.approx(res.std["m_ch"] / res.values["m_ch"])
    rho = np.array(rep["correlation"]["matrix"])
    assert np.allclose(np.diag(rho), 1.0) and np.allclose(rho, rho.T)
    assert "C_l" in res.table() and "steer_left" in res.table()


def test_stick_slip_validation_splits_moving_and_sticking_rows():
    from qomni.ident.validation import stick_slip_comparison

    (block,) = synthetic_blocks(noise={}, names=("steer_left",))
    stuck = np.abs(block.velocity) < 0.2
    f_s = P_TRUE[2] + P_TRUE[9] * np.max(np.abs(block.Theta[:, 9]))   # d_cl + 2k d_cw
    inside = block.tau.copy()
    inside[stuck] = 0.5 * f_s * np.sign(block.velocity[stuck])        # held by static friction
    outside = inside.copy()
    outside[stuck] = 2.0 * f_s                                         # more than stiction can hold
    for tau, sticking_error in ((inside, False), (outside, True)):
        b = RegressorBlock(block.Theta, tau, block.velocity, block.channel)
        (res,) = stick_slip_comparison([b], P_TRUE, 0.2).values()
        assert res["moving"]["nrmse"] == pytest.approx(0.0, abs=1e-12)
        assert res["sticking"]["n_rows"] == stuck.sum() and res["sticking"]["static_friction"] == pytest.approx(f_s)
        assert (res["sticking"]["nrmse"] > 0.1) == sticking_error
        assert res["moving_share"] == pytest.approx(1 - stuck.mean())
