"""χ² gate thresholds for the EKF, without importing scipy.stats where it can be helped.

``scipy.stats`` costs about 0.55 s to import on the project's 2-core machine, a third of a
whole 20 s ``twin run`` process, and the filter needs only four numbers from it: the χ²
quantiles at 1 − 1e-4 (the default ``gate_probability``) and 1 − 1e-9 (the IMU gate) for 1
and 2 degrees of freedom. Those are stored here as the exact floats scipy gives (written with
``float.hex``); any other probability is asked of scipy, as before. The closed forms
(−2 ln p for 2 dof, an inverse-erf for 1 dof) would differ in the last bits, and a gate
moved by one ulp can flip a decision and change a run: tests/test_estimator.py checks
that this table equals scipy's answer on the installed scipy.
"""
from __future__ import annotations

# (probability, dof) -> float(scipy.stats.chi2.ppf(1.0 - probability, dof)), scipy 1.17.1
_TABLE = {
    (1e-4, 1): float.fromhex("0x1.e45fe3a3b14d1p+3"),  # 15.136705226623606
    (1e-4, 2): float.fromhex("0x1.26bb1bbb55553p+4"),  # 18.420680743952584
    (1e-9, 1): float.fromhex("0x1.2a99618e998cdp+5"),  # 37.32489310651872
    (1e-9, 2): float.fromhex("0x1.4b927f3a57808p+5"),  # 41.446531730456684
}


def chi2_gate(probability: float, dof: int) -> float:
    """The χ² quantile with ``dof`` degrees of freedom that a fitting measurement exceeds with
    ``probability``: ``float(scipy.stats.chi2.ppf(1.0 - probability, dof))``, bit for bit."""
    value = _TABLE.get((probability, dof))
    if value is None:
        from scipy.stats import chi2

        value = float(chi2.ppf(1.0 - probability, dof))
    return value
