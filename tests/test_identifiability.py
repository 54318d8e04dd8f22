"""Table 1 of the paper by QR (Section 6.1)."""
import numpy as np
import pytest

from qomni.ident import identifiability as I
from qomni.datasheet import DataSheet
from qomni.ident.symbolic import PARAMETER_NAMES

G = DataSheet.load().geometry
ALL = PARAMETER_NAMES
STEERING = ("C_l", "d_vl", "d_cl", "C_r", "d_vr", "d_cr")
PAPER_TABLE1 = {
    "1": STEERING,
    "2": ALL,
    "3": ("m_ch", "d_vw", "d_cw"),
    "4": ("C_ch", "d_vw", "d_cw"),
    "2 (alpha_v=0)": ("m_ch", "d_vw", "d_cw"),
    "1, 2 (alpha_v=0), 4": ALL[:10],  # all but B_w
}


def test_table1_sign_coulomb():
    """With Coulomb friction as sign() (eps -> 0) the QR gives exactly the paper's Table 1."""
    table = I.table1(G, eps=0.0)
    assert {k: v.independent for k, v in table.items()} == PAPER_TABLE1


def test_table1_paper_eps():
    """With the paper's tanh(v/0.01) every row is the same except mode 1, where d_cw is (weakly)
    independent because tanh((a/r) v/eps) is not proportional to tanh(v/eps)."""
    table = I.table1(G, eps=0.01)
    expected = dict(PAPER_TABLE1, **{"1": STEERING + ("d_cw",)})
    assert {k: v.independent for k, v in table.items()} == expected
    assert all(r.rank == len(r.independent) for r in table.values())


def test_regrouping_coefficients():
    a_r, R = G.a / G.r, np.hypot(G.l, G.b) / 2
    res = I.analyse((4,), G)
    j = res.dependent.index("B_w")
    np.testing.assert_allclose(res.kappa[res.independent.index("C_ch"), j], 4 * ((R + G.a) / G.r) ** 2)
    np.testing.assert_allclose(res.kappa[res.independent.index("C_ch"), res.dependent.index("C_l")], 1)
    comb = I.table1(G)["1, 2 (alpha_v=0), 4"]
    assert comb.dependent == ("B_w",)
    kap = dict(zip(comb.independent, comb.kappa[:, 0]))
    np.testing.assert_allclose([kap["C_l"], kap["C_r"], kap["m_ch"], kap["C_ch"]],
                               [2 * a_r**2, 2 * a_r**2, 4 / G.r**2, 4 * ((R + G.a) / G.r) ** 2 - 4 * a_r**2],
                               rtol=1e-8)
    p = np.arange(1.0, 12.0)
    pb = comb.base_parameters(p)
    np.testing.assert_allclose(pb, p[:10] + comb.kappa[:, 0] * p[10])


def test_priority_decides_among_collinear_columns():
    assert I.analyse((4,), G, priority=PARAMETER_NAMES).independent == ("C_l", "d_vw", "d_cw")
    assert I.analyse((3,), G, priority=PARAMETER_NAMES[::-1]).independent == ("d_vw", "d_cw", "B_w")


def test_errors():
    with pytest.raises(ValueError, match="permutation"):
        I.independent_parameters(np.ones((20, 11)), priority=ALL[:10])
    with pytest.raises(ValueError, match="columns"):
        I.independent_parameters(np.ones((20, 10)))
    with pytest.raises(ValueError, match="mode"):
        I.random_regressor(7, G)
