"""Recursive least squares with directional forgetting, for the online twin.

The rigid model is linear in its unknowns (see :mod:`chaintwin.model.rigid`),
``y = φᵀθ + e``, one row ``φ`` per window (or per sample, or per cycle). The
online twin updates the estimate θ with every row instead of solving the
batch problem again (docs/design.md, section 3).

Update
------
With ``P`` the (unscaled) covariance, ``r = φᵀPφ`` and the a-priori error
``e = y − φᵀθ``::

    θ ← θ + P·φ·e/(1 + r)
    P ← P − ε·Pφφᵀ P/(1 + ε·r),       ε = λ − (1 − λ)/r

This is the **directional forgetting** of Kulhavý (R. Kulhavý, "Restricted
exponential forgetting in real-time identification", Automatica 23(5),
1987, 589-600; analysed by S. Bittanti, P. Bolzern and M. Campi,
"Convergence and exponential convergence of identification algorithms with
directional forgetting factor", Automatica 26(5), 1990). In
information form ``R = P⁻¹`` it reads ``R ← R + ε·φφᵀ``: the old information
is discounted by the forgetting factor λ **only in the direction φ that the
new row excites** (in that direction the information becomes
``λ·(old + new)``), and left alone in every other direction. With λ = 1,
ε = 1 and the update is ordinary recursive least squares, which equals the
batch least-squares solution regularised by ``‖θ‖²/delta`` (the prior
``θ₀ = 0``, ``P₀ = delta·I``) to rounding.

Why not plain exponential forgetting
------------------------------------
``P ← P/λ`` after each update forgets in all directions. When the regressor
carries no information (standstill: φ = 0; constant speed: φ always along
the same direction) nothing replaces what is forgotten and P grows like
``λ⁻ᵏ`` ("covariance wind-up", 10 000 rows at λ = 0.95 overflow): the next
informative row then throws the estimate about. Directional forgetting
cannot wind up:

* φ = 0 (or ``r ≤ dead_zone``): the row is skipped, P and θ stay as they are;
* φ always along one direction ``v``: the information along ``v`` converges
  to ``λ·|φ|²/(1 − λ)`` (bounded below, so P is bounded above) and the
  information in the other directions is kept.

The price: with rows spread over all p directions, each direction is
discounted about once every p rows, so the memory is about ``p/(1 − λ)``
rows instead of ``1/(1 − λ)``; choose λ for that (p = 2, λ = 0.98 tracks a
parameter step to 2 % in some 360 rows).

A caveat: a row with a tiny but non-zero φ (noise at standstill) still
triggers the full discount ``λ`` in its direction, so P can grow there up to
about ``(1 − λ)/(λ·|φ|²)``. Leave standstill out of the rows (as
:func:`~chaintwin.model.windows.window_integrals` does), raise
``dead_zone`` (``r = φᵀPφ`` is the share of new against existing information
along φ), or bound the trace with ``max_trace``.

Numerics
--------
P is kept as a square-root factor ``P = S·Sᵀ`` updated as in Potter's
square-root filter, ``S ← S·(I − γ·f·fᵀ)`` with ``f = Sᵀφ`` and
``γ = ε/(s·(1 + s))``, ``s = √(λ·(1 + r))``: P stays symmetric and positive
definite by construction (``det(I − γ·f·fᵀ) = 1/s > 0``), and the step is
exact in exact arithmetic. The update loop is compiled with numba.

Parameter covariance
--------------------
``covariance_ = σ²·P`` with σ² the running residual variance estimate
``Σ λ^(k−j)·e_j²/(1 + r_j)`` over ``Σ λ^(k−j) − p`` (for λ = 1 exactly the
regularised residual sum of squares over ``n − p``, as in batch least
squares). It assumes white residuals; with forgetting σ² is an average over
about the last ``1/(1 − λ)`` informative rows.
"""

from __future__ import annotations

import math
from typing import Self

import numpy as np
import numpy.typing as npt
from numba import njit

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError, NotFittedError

__all__ = ["RecursiveLeastSquares"]


# stats vector of the compiled loop
_S_RES = 0  # discounted sum of a-posteriori squared errors
_N_EFF = 1  # discounted row count
_N_ROWS = 2  # rows seen
_N_SKIP = 3  # rows inside the dead zone


@njit(cache=True, nogil=True)
def _update(
    x: np.ndarray,
    y: np.ndarray,
    theta: np.ndarray,
    s: np.ndarray,
    stats: np.ndarray,
    lam: float,
    dead_zone: float,
    max_trace: float,
) -> None:  # pragma: no cover - compiled; tested through RecursiveLeastSquares
    """Process the rows of ``x``/``y`` in order, updating ``theta``, ``s``, ``stats`` in place."""
    n, p = x.shape
    f = np.empty(p)
    g = np.empty(p)
    for k in range(n):
        stats[_N_ROWS] += 1.0
        # f = Sᵀφ, r = φᵀPφ = fᵀf
        r = 0.0
        for j in range(p):
            acc = 0.0
            for i in range(p):
                acc += s[i, j] * x[k, i]
            f[j] = acc
            r += acc * acc
        if not r > dead_zone:  # also catches NaN
            stats[_N_SKIP] += 1.0
            continue
        # g = S f = Pφ, e = y − φᵀθ
        e = y[k]
        for i in range(p):
            acc = 0.0
            for j in range(p):
                acc += s[i, j] * f[j]
            g[i] = acc
            e -= x[k, i] * theta[i]
        one_r = 1.0 + r
        c = e / one_r
        for i in range(p):
            theta[i] += g[i] * c
        eps = 1.0 if lam == 1.0 else lam - (1.0 - lam) / r
        root = math.sqrt(lam * one_r)  # √(1 + ε·r)
        gamma = eps / (root * (1.0 + root))
        for i in range(p):
            gi = gamma * g[i]
            for j in range(p):
                s[i, j] -= gi * f[j]
        stats[_S_RES] = lam * stats[_S_RES] + e * c
        stats[_N_EFF] = lam * stats[_N_EFF] + 1.0
        if max_trace > 0.0:
            tr = 0.0
            for i in range(p):
                for j in range(p):
                    tr += s[i, j] * s[i, j]
            if tr > max_trace:
                scale = math.sqrt(max_trace / tr)
                for i in range(p):
                    for j in range(p):
                        s[i, j] *= scale


def _no_stats() -> FloatArray:
    out = np.zeros(4, dtype=np.float64)
    out.flags.writeable = False
    return out


class RecursiveLeastSquares:
    """Recursive least squares with Kulhavý's directional forgetting.

    Solves ``y ≈ X·θ`` one row at a time (see the module docstring for the
    update, why directional forgetting, and the numerics).

    Parameters
    ----------
    forgetting : float
        Forgetting factor λ in (0, 1]; 1 keeps every row (equals batch least
        squares). Below 1, each row discounts the information only along its
        own direction, so with rows spread over all p directions the memory
        is about ``p/(1 − λ)`` rows (plain exponential forgetting:
        ``1/(1 − λ)``); along a direction that is never excited it is kept.
    delta : float
        Initial covariance ``P₀ = delta·I`` (θ₀ = 0): a prior of standard
        deviation ``√delta`` in the units of θ. With λ = 1 the estimate equals
        ridge regression with penalty ``1/delta``.
    max_trace : float, optional
        When given, P is scaled down whenever its trace exceeds this bound
        (a hard bound on top of directional forgetting; off by default, so
        that λ = 1 stays exact least squares).
    dead_zone : float
        Rows with ``φᵀPφ ≤ dead_zone`` carry no information and are skipped
        (no forgetting, no update, no residual). ``φᵀPφ`` is dimensionless:
        the row's information along φ relative to what is already known.

    Attributes
    ----------
    theta_ : ndarray of float, shape (p,)
        The estimate, in the units of ``y`` per unit of each column of ``X``.
    covariance_ : ndarray of float, shape (p, p)
        Parameter covariance ``σ²·P``.
    stderr_ : ndarray of float, shape (p,)
        Standard errors, ``√diag(covariance_)``.
    residual_variance_ : float
        The running residual variance estimate σ², units of ``y`` squared.
    n_updates_ : int
        Rows processed since the last ``fit`` (skipped rows included).
    n_skipped_ : int
        Rows skipped as uninformative (``φᵀPφ ≤ dead_zone``).
    n_features_in_ : int
        Number of columns p.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> X = rng.normal(size=(200, 2))
    >>> rls = RecursiveLeastSquares().fit(X, X @ np.array([2.0, -1.0]))
    >>> np.round(rls.theta_, 6).tolist()
    [2.0, -1.0]
    """

    # state of a fit, set by fit()/partial_fit(); __init__ only stores settings
    _theta: FloatArray | None = None
    _sqrt_p: FloatArray | None = None
    _stats: FloatArray = _no_stats()

    def __init__(
        self,
        *,
        forgetting: float = 1.0,
        delta: float = 1.0e6,
        max_trace: float | None = None,
        dead_zone: float = 1.0e-12,
    ) -> None:
        self.forgetting = forgetting
        self.delta = delta
        self.max_trace = max_trace
        self.dead_zone = dead_zone

    def __repr__(self) -> str:
        return (
            f"RecursiveLeastSquares(forgetting={self.forgetting!r}, delta={self.delta!r}, "
            f"max_trace={self.max_trace!r}, dead_zone={self.dead_zone!r})"
        )

    # ------------------------------------------------------------ checks
    def _check_settings(self) -> None:
        lam = self.forgetting
        if not (isinstance(lam, int | float) and math.isfinite(lam) and 0.0 < lam <= 1.0):
            raise EstimationError(f"forgetting={lam!r} must lie in (0, 1]; 1 means no forgetting")
        if not (math.isfinite(self.delta) and self.delta > 0.0):
            raise EstimationError(f"delta={self.delta!r} must be a positive number")
        if self.max_trace is not None and not (
            math.isfinite(self.max_trace) and self.max_trace > 0.0
        ):
            raise EstimationError(f"max_trace={self.max_trace!r} must be None or positive")
        if not (math.isfinite(self.dead_zone) and self.dead_zone >= 0.0):
            raise EstimationError(f"dead_zone={self.dead_zone!r} must be a number ≥ 0")

    @staticmethod
    def _rows(X: npt.ArrayLike, y: npt.ArrayLike | float) -> tuple[FloatArray, FloatArray]:
        x = np.asarray(X, dtype=np.float64)
        if x.ndim == 1:
            x = x[np.newaxis, :]
        if x.ndim != 2 or x.shape[1] == 0:
            raise EstimationError(
                f"X must have shape (n, p) or (p,) with p ≥ 1, got shape {np.shape(X)}"
            )
        yy = np.atleast_1d(np.asarray(y, dtype=np.float64))
        if yy.ndim != 1 or yy.shape[0] != x.shape[0]:
            raise EstimationError(
                f"y must hold one value per row of X ({x.shape[0]}), got shape {np.shape(y)}"
            )
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(yy))):
            raise EstimationError("X or y holds NaN or infinite values; remove those rows")
        return np.ascontiguousarray(x), np.ascontiguousarray(yy)

    # ----------------------------------------------------------- fitting
    def _reset(self, p: int) -> None:
        self._theta = np.zeros(p, dtype=np.float64)
        self._sqrt_p = math.sqrt(self.delta) * np.eye(p, dtype=np.float64)
        self._stats = np.zeros(4, dtype=np.float64)

    def fit(self, X: npt.ArrayLike, y: npt.ArrayLike | float) -> Self:
        """Start afresh (θ = 0, P = delta·I) and process the rows in order.

        Parameters
        ----------
        X : array_like, shape (n, p) or (p,)
            Regressor rows.
        y : array_like, shape (n,) or scalar
            Targets, one per row.

        Returns
        -------
        RecursiveLeastSquares
            ``self``, fitted.

        Raises
        ------
        EstimationError
            For invalid settings, shapes or non-finite values.
        """
        self._check_settings()
        x, yy = self._rows(X, y)
        self._reset(x.shape[1])
        return self._process(x, yy)

    def partial_fit(self, X: npt.ArrayLike, y: npt.ArrayLike | float) -> Self:
        """Update the estimate with more rows, processed one at a time, in order.

        The first call on an unfitted estimator starts from θ = 0, P = delta·I.

        Parameters
        ----------
        X : array_like, shape (n, p) or (p,)
            Regressor rows (p as in earlier calls).
        y : array_like, shape (n,) or scalar
            Targets, one per row.

        Returns
        -------
        RecursiveLeastSquares
            ``self``, updated.

        Raises
        ------
        EstimationError
            For invalid settings, shapes (a different p than before) or
            non-finite values.
        """
        self._check_settings()
        x, yy = self._rows(X, y)
        if self._theta is None:
            self._reset(x.shape[1])
        elif x.shape[1] != self._theta.shape[0]:
            raise EstimationError(
                f"X has {x.shape[1]} columns but the estimator was fitted with "
                f"{self._theta.shape[0]}; call fit() to start afresh"
            )
        return self._process(x, yy)

    def _process(self, x: FloatArray, y: FloatArray) -> Self:
        assert self._theta is not None and self._sqrt_p is not None
        _update(
            x,
            y,
            self._theta,
            self._sqrt_p,
            self._stats,
            float(self.forgetting),
            float(self.dead_zone),
            float(self.max_trace) if self.max_trace is not None else 0.0,
        )
        return self

    # ---------------------------------------------------------- results
    def _fitted(self) -> tuple[FloatArray, FloatArray]:
        if self._theta is None or self._sqrt_p is None:
            raise NotFittedError(
                "this RecursiveLeastSquares is not fitted yet; call fit(X, y) or "
                "partial_fit(X, y) first"
            )
        return self._theta, self._sqrt_p

    @property
    def theta_(self) -> FloatArray:
        """The estimate θ, shape (p,) (a copy)."""
        return self._fitted()[0].copy()

    @property
    def n_features_in_(self) -> int:
        """Number of columns p."""
        return int(self._fitted()[0].shape[0])

    @property
    def n_updates_(self) -> int:
        """Rows processed since the last ``fit`` (skipped rows included)."""
        self._fitted()
        return int(self._stats[_N_ROWS])

    @property
    def n_skipped_(self) -> int:
        """Rows skipped as uninformative (``φᵀPφ ≤ dead_zone``)."""
        self._fitted()
        return int(self._stats[_N_SKIP])

    @property
    def p_matrix_(self) -> FloatArray:
        """The unscaled covariance P (``σ²·P`` is ``covariance_``), shape (p, p)."""
        s = self._fitted()[1]
        p: FloatArray = s @ s.T
        return p

    @property
    def residual_variance_(self) -> float:
        """Running residual variance σ², units of ``y`` squared (NaN before any informative row).

        ``Σ λ^(k−j)·e_j²/(1 + r_j)`` over ``max(Σ λ^(k−j) − p, 1)``.
        """
        theta = self._fitted()[0]
        n_eff = float(self._stats[_N_EFF])
        if n_eff <= 0.0:
            return math.nan
        dof = max(n_eff - int(theta.shape[0]), 1.0)
        return float(self._stats[_S_RES]) / dof

    @property
    def covariance_(self) -> FloatArray:
        """Parameter covariance ``σ²·P``, shape (p, p)."""
        cov: FloatArray = self.residual_variance_ * self.p_matrix_
        return cov

    @property
    def stderr_(self) -> FloatArray:
        """Standard errors ``√diag(covariance_)``, shape (p,)."""
        diag: FloatArray = np.sqrt(np.diag(self.covariance_))
        return diag

    def predict(self, X: npt.ArrayLike) -> FloatArray:
        """Predict ``X·θ``.

        Parameters
        ----------
        X : array_like, shape (n, p) or (p,)
            Regressor rows.

        Returns
        -------
        ndarray of float, shape (n,)
            Predictions, units of ``y``.

        Raises
        ------
        NotFittedError
            Before ``fit``/``partial_fit``.
        EstimationError
            For a wrong number of columns or non-finite values.
        """
        theta = self._fitted()[0]
        x = np.asarray(X, dtype=np.float64)
        if x.ndim == 1:
            x = x[np.newaxis, :]
        if x.ndim != 2 or x.shape[1] != theta.shape[0]:
            raise EstimationError(f"X must have {theta.shape[0]} columns, got shape {np.shape(X)}")
        if not np.all(np.isfinite(x)):
            raise EstimationError("X holds NaN or infinite values")
        out: FloatArray = x @ theta
        return out
