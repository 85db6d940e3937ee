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


@pytest.mark.parametrize("dfn, dfd", [(1, 1), (2, 5), (2, 57), (3, 17), (2, 1000), (2, 2_000_000)])
def test_fisher_quantiles_are_scipy_stats(dfn, dfd):
    # the held principal point's test (F(2, dof) at 1e-3) took them from scipy.stats: 0.5 s of every adjust.
    # scipy.stats.f.isf goes through 1 - q (2e-5 relative off at 1e-12): judged by its survival function
    x = Q.f_isf(Q_TAIL, dfn, dfd)
    assert np.allclose(stats.f.sf(x, dfn, dfd), Q_TAIL, rtol=1e-10, atol=0)
    middle = Q_TAIL >= 1e-4
    assert np.allclose(x[middle], stats.f.isf(Q_TAIL[middle], dfn, dfd), rtol=1e-7, atol=0)
