"""S and J from op and pv alone: the Hammerstein estimation (Section 5.3.1).

Without a recorded valve position, the data-driven valve model of Choudhury,
Thornhill & Shah (2005) (Section 5.1, Fig. 10) is fitted together with a linear
process, op -> valve(S, J) -> G(q) -> pv.  The package holds the estimation in the
order it runs:

* :mod:`~stictiondiag.stiction.hammerstein.fit`: :func:`fit_hammerstein`, the
  procedure (its module docstring states the model, the search and the intervals);
* :mod:`~stictiondiag.stiction.hammerstein.search`: the coarse-to-fine search over
  (S, J) and the linear-valve fit it is compared with;
* :mod:`~stictiondiag.stiction.hammerstein.kernels`: the compiled evaluation of a
  batch of (S, J) pairs (valve run, one-sign least squares), threaded;
* :mod:`~stictiondiag.stiction.hammerstein.columns`: the regressors of the linear
  part (the high-passed valve output and its lags) and their normal equations.

What it shares with the estimator from mv (the valve variants, the profile-cost
intervals, the noise level) is in :mod:`stictiondiag.stiction.valvefit`.
"""

from stictiondiag.stiction.hammerstein.fit import first_extreme, fit_hammerstein

__all__ = ["first_extreme", "fit_hammerstein"]
