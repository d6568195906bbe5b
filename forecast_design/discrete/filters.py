"""The one discrete filter implementation: delta-operator second-order sections and the numba shim.

The recursion is documented in :mod:`forecast_design.discrete`; :func:`sos_step` is the one
implementation the simulator, the program reference and (as C text) the export run.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import ParameterError

try:  # numba is optional: without it the kernels run as (slow) plain Python.
    from numba import njit as _numba_njit
    from numba import prange

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    _numba_njit = None
    prange = range
    HAVE_NUMBA = False


def njit(func=None, *, inline: str = "never", parallel: bool = False):
    """The project's one numba shim: ``numba.njit(cache=True, inline=..., parallel=...)``, or the plain function.

    Parameters
    ----------
    func : callable, optional
        The function (``@njit`` or ``njit(f, inline="always")``).
    inline : str
        numba's IR-level inlining at jitted call sites (``"never"`` or ``"always"``).
    parallel : bool
        Run the function's ``prange`` loops (:data:`prange`, ``range`` without numba) on
        numba's thread pool.

    Returns
    -------
    callable
        The compiled function (the function itself without numba).
    """
    def wrap(f):
        if _numba_njit is None:
            return f
        if parallel:
            return _numba_njit(cache=True, inline=inline, parallel=True)(f)
        return _numba_njit(cache=True, inline=inline)(f)

    return wrap if func is None else wrap(func)



@njit
def sos_step(sos, state, x):
    """Advance a cascade of delta-operator second-order sections by one sample (in place).

    Parameters
    ----------
    sos : ndarray, shape (n_sections, 6)
        Delta sections, rows ``[b0, b1, b2, 1, a1, a2]`` (module docstring).
    state : ndarray, shape (n_sections, 2)
        Accumulator states ``s1, s2``; updated in place.
    x : float
        Input sample.

    Returns
    -------
    float
        Output sample. The arithmetic is done in the dtype of ``sos``/``state``
        (float32 arrays give float32 arithmetic, bit for bit the emitted C
        ``float`` code built without FMA contraction).
    """
    y = x
    for i in range(sos.shape[0]):
        xi = y
        y = sos[i, 0] * xi + state[i, 0]
        t1 = sos[i, 1] * xi - sos[i, 4] * y + state[i, 1]
        t2 = sos[i, 2] * xi - sos[i, 5] * y
        state[i, 0] = state[i, 0] + t1
        state[i, 1] = state[i, 1] + t2
    return y


@njit
def sos_filter(sos, state, x, y):
    """Run :func:`sos_step` over an input array.

    Parameters
    ----------
    sos : ndarray, shape (n_sections, 6)
        Delta sections.
    state : ndarray, shape (n_sections, 2)
        States, updated in place.
    x : ndarray, shape (n,)
        Input.
    y : ndarray, shape (n,)
        Output, written in place.
    """
    for n in range(x.shape[0]):
        y[n] = sos_step(sos, state, x[n])


#: The delta section of the first difference ``1 - z^-1 = rho / (rho + 1)``.
FIRST_DIFFERENCE = (1.0, 0.0, 0.0, 1.0, 1.0, 0.0)

# Roots with |imag| below this fraction of their modulus are real (np.roots splits a repeated
# real root, e.g. a binomial Q filter's, into a pair with a tiny imaginary part).
_REAL_TOL = 1e-9


def delta_to_sos(dsos: np.ndarray) -> np.ndarray:
    """Convert delta sections to scipy's shift-operator sections (float64).

    Parameters
    ----------
    dsos : ndarray, shape (n, 6)
        Delta sections ``[b0, b1, b2, 1, a1, a2]`` in ``rho = z - 1``.

    Returns
    -------
    ndarray, shape (n, 6)
        ``[b0, b1, b2, 1, a1, a2]`` in ``z^-1`` (``scipy.signal.sosfilt``
        layout), the same transfer function. First-order rows (``b2 = a2 =
        0``) map to first-order shift sections.
    """
    d = np.asarray(dsos, dtype=float).reshape(-1, 6)
    out = np.zeros_like(d)
    for row, (b0, b1, b2, _, a1, a2) in zip(out, d):
        if b2 == 0.0 and a2 == 0.0:  # (b0 rho + b1) / (rho + a1)
            row[:] = (b0, b1 - b0, 0.0, 1.0, a1 - 1.0, 0.0)
        else:
            row[:] = (b0, b1 - 2.0 * b0, b0 - b1 + b2, 1.0, a1 - 2.0, 1.0 - a1 + a2)
    return out


def sos_to_delta(sos: np.ndarray) -> np.ndarray:
    """Convert scipy shift-operator sections to delta sections (float64).

    Parameters
    ----------
    sos : ndarray, shape (n, 6)
        ``[b0, b1, b2, a0, a1, a2]`` in ``z^-1``, ``a0 != 0``.

    Returns
    -------
    ndarray, shape (n, 6)
        The same transfer function as delta sections. The conversion is
        exact algebra but cannot restore precision that shift-operator
        coefficients have already lost (prefer :meth:`DiscreteTF.to_delta_sos`).
    """
    s = np.asarray(sos, dtype=float).reshape(-1, 6)
    out = np.zeros_like(s)
    for row, (b0, b1, b2, a0, a1, a2) in zip(out, s):
        b0, b1, b2, a1, a2 = b0 / a0, b1 / a0, b2 / a0, a1 / a0, a2 / a0
        if b2 == 0.0 and a2 == 0.0:
            row[:] = (b0, b1 + b0, 0.0, 1.0, a1 + 1.0, 0.0)
        else:
            row[:] = (b0, b1 + 2.0 * b0, b0 + b1 + b2, 1.0, a1 + 2.0, 1.0 + a1 + a2)
    return out


class DiscreteFilter:
    """A running discrete filter: delta-operator second-order sections.

    Parameters
    ----------
    dtf : DiscreteTF or ndarray
        The discrete TF (realised with :meth:`DiscreteTF.to_delta_sos`) or a
        delta-SOS array of shape (n_sections, 6) (rows ``[b0, b1, b2, 1, a1,
        a2]`` in ``rho = z - 1``; convert scipy sections with :func:`sos_to_delta`).
    dtype : numpy dtype
        ``np.float64`` (default) or ``np.float32``: coefficients, states and
        arithmetic (float32 emulates a C ``float`` implementation).

    Notes
    -----
    The recursion is the module docstring's, implemented once in
    :func:`sos_step`; the simulator calls the same function. This object is
    stateful on purpose (it is a running filter); the coefficients are
    read-only.
    """

    __slots__ = ("sos", "state", "dtf")

    def __init__(self, dtf: "DiscreteTF | np.ndarray", dtype: Any = np.float64) -> None:
        if hasattr(dtf, "to_delta_sos"):
            sos = dtf.to_delta_sos(dtype)
            self.dtf = dtf
        else:
            sos = np.ascontiguousarray(np.atleast_2d(np.asarray(dtf)), dtype=dtype)
            if sos.ndim != 2 or sos.shape[1] != 6 or not np.all(sos[:, 3] == 1.0):
                raise ParameterError("DiscreteFilter sos must have shape (n, 6) with a0 == 1 in column 3",
                                     name="sos", value=dtf)
            self.dtf = None
        sos.flags.writeable = False
        self.sos = sos
        self.state = np.zeros((sos.shape[0], 2), dtype=sos.dtype)

    def reset(self) -> None:
        """Zero the states."""
        self.state[:] = 0.0

    def step(self, x: float) -> float:
        """Filter one sample; return the output."""
        return float(sos_step(self.sos, self.state, self.sos.dtype.type(x)))

    def filter(self, x: np.ndarray) -> np.ndarray:
        """Filter a whole array from the current state (the state is advanced).

        Parameters
        ----------
        x : ndarray, shape (n,)
            Input samples.

        Returns
        -------
        ndarray, shape (n,)
            Output samples (in the filter dtype).
        """
        x = np.ascontiguousarray(x, dtype=self.sos.dtype)
        y = np.empty_like(x)
        sos_filter(self.sos, self.state, x, y)
        return y


# Kernels whose on-disk cache has been checked against their callees (once per process).
_KERNEL_CHECKED: list = []


def check_kernel_cache(kernel: Any, modules: Any) -> None:
    """Drop the on-disk numba cache of ``kernel`` once per process when a module it calls has changed.

    numba keys a cached function by its *own* file only, but a compiled function carries the
    code of the jitted functions it calls; an edit there (e.g. a new section recursion) would
    otherwise leave a stale compiled kernel running the old code. A hash of the sources of
    ``modules`` is kept beside the cache; a mismatch flushes it (one recompilation).

    Parameters
    ----------
    kernel : numba dispatcher
        A ``cache=True`` jitted function (anything else is ignored).
    modules : sequence of module
        The modules whose sources the kernel's compiled code depends on (its own included).
    """
    if kernel in _KERNEL_CHECKED:
        return
    _KERNEL_CHECKED.append(kernel)
    import hashlib
    from pathlib import Path

    cache = getattr(kernel, "_cache", None)
    path = getattr(cache, "_cache_path", None)
    if cache is None or path is None:
        return
    try:
        digest = hashlib.sha256()
        for mod in modules:
            digest.update(Path(mod.__file__).read_bytes())
        stamp = Path(path) / f"{kernel.__module__.rsplit('.', 1)[-1]}.{kernel.__name__}.deps"
        current = digest.hexdigest()
        if not stamp.exists() or stamp.read_text() != current:
            cache.flush()
            stamp.write_text(current)
    except OSError:  # read-only install: numba then caches elsewhere or not at all
        pass
