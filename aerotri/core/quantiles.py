"""Quantiles of the normal, chi-square, Student t and Fisher F distributions for the statistical tests.

From ``scipy.special``, exact to the last digits of ``scipy.stats``'s: importing ``scipy.stats`` (and with it
``scipy.optimize``) costs 0.5-0.7 s of every command's start that tests anything (`aerotri adjust` on a small
block: 4 s), ``scipy.special`` 0.1 s. Upper-tail (``isf``) forms are computed directly, not as ``ppf(1 - q)``,
so that small type I errors keep their precision.
"""

from __future__ import annotations

from scipy.special import betaincinv, gammainccinv, gammaincinv, ndtri, stdtrit


def norm_isf(q):
    """z with P(Z > z) = q for a standard normal Z (``scipy.stats.norm.isf``)."""
    return -ndtri(q)


def norm_ppf(q):
    """z with P(Z <= z) = q (``scipy.stats.norm.ppf``)."""
    return ndtri(q)


def chi2_isf(q, dof):
    """x with P(X > x) = q for X chi-square with ``dof`` degrees of freedom (``scipy.stats.chi2.isf``)."""
    return 2.0 * gammainccinv(0.5 * dof, q)


def chi2_ppf(q, dof):
    """x with P(X <= x) = q (``scipy.stats.chi2.ppf``)."""
    return 2.0 * gammaincinv(0.5 * dof, q)


def t_isf(q, dof):
    """t with P(T > t) = q for Student's T with ``dof`` degrees of freedom (``scipy.stats.t.isf``)."""
    return -stdtrit(dof, q)


def f_isf(q, dfn, dfd):
    """x with P(F > x) = q for Fisher's F with ``dfn``, ``dfd`` degrees of freedom (``scipy.stats.f.isf``): by
    dfd / (dfd + dfn F) ~ Beta(dfd / 2, dfn / 2), whose lower tail at q is the F's upper tail."""
    y = betaincinv(0.5 * dfd, 0.5 * dfn, q)
    return dfd * (1.0 - y) / (dfn * y)
