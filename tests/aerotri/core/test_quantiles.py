"""The tests' quantiles from scipy.special against scipy.stats's, from the tails to the middle."""

import numpy as np
import pytest
from scipy import stats

from aerotri.core import quantiles as Q

Q_TAIL = np.array([1e-12, 1e-9, 1e-6, 1e-4, 5e-4, 1e-3, 0.025, 0.05, 0.1, 0.3, 0.5, 0.8, 0.95, 0.999])


@pytest.mark.parametrize("dof", [1, 2, 3, 2.5, 5, 10, 57, 1000])
def test_chi_square_and_t_quantiles_are_scipy_stats(dof):
    assert np.allclose(Q.chi2_isf(Q_TAIL, dof), stats.chi2.isf(Q_TAIL, dof), rtol=1e-12, atol=0)
    assert np.allclose(Q.chi2_ppf(Q_TAIL, dof), stats.chi2.ppf(Q_TAIL, dof), rtol=1e-12, atol=0)
    assert np.allclose(Q.t_isf(Q_TAIL, dof), stats.t.isf(Q_TAIL, dof), rtol=1e-12, atol=1e-14)


def test_normal_quantiles_are_scipy_stats_and_the_textbook_values():
    assert np.allclose(Q.norm_isf(Q_TAIL), stats.norm.isf(Q_TAIL), rtol=1e-13, atol=1e-15)
    assert np.allclose(Q.norm_ppf(Q_TAIL), stats.norm.ppf(Q_TAIL), rtol=1e-13, atol=1e-15)
    # Baarda's data snooping: alpha 0.1 % two-sided 3.29, power 80 % 0.84; chi-square 3 dof at 5 % 7.81
    assert round(float(Q.norm_isf(0.0005)), 2) == 3.29 and round(float(Q.norm_ppf(0.8)), 2) == 0.84
    assert round(float(Q.chi2_isf(0.05, 3)), 2) == 7.81
