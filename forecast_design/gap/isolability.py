"""Which effects one log can tell apart: the isolability matrix of the gap candidates.

For two candidates A and B the
*separation* is the sine of the largest principal angle between the span of A's
feature columns and the span of B's features together with the calibration
columns, on held-out data, and the other way round; the pair's separation is the
larger of the two (one direction suffices: a nested law is told apart when its
extra features are). Feature directions carrying less than ``1e-6`` of a
candidate's variance are dropped first: the excitation does not carry them. A
pair is *isolable* when its separation is at least ``threshold`` (0.3: at least
a 17 degree angle). The pseudo-word ``calibration`` stands for the re-calibration
of ``J_m``, ``d_m`` and ``k``. A torque gain scales everything the motor does, so its
signature is the nominal model's own motor torque, which lies in the span of the
re-calibration: a torque gain is told from the re-calibration only by the latter's
datasheet bound, and the matrix says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..effects import Effect
from .candidates import CandidateFit, _calibration
from .residuals import GapData
from .structures import _design_matrix

__all__ = ["Isolability", "isolability", "ISOLABILITY_THRESHOLD", "CALIBRATION"]

#: Smallest separation (sine of the largest principal angle) at which two candidates count as isolable [-].
ISOLABILITY_THRESHOLD = 0.3
#: Pseudo-word of the isolability matrix for the nominal re-calibration.
CALIBRATION = "calibration"


def _basis(M: np.ndarray, rel: float = 1e-3) -> np.ndarray:
    """Orthonormal basis of the column space, dropping directions with < rel^2 of the largest variance."""
    if M.size == 0:
        return np.zeros((M.shape[0], 0))
    norms = np.sqrt(np.sum(M ** 2, axis=0))
    M = M[:, norms > 0] / norms[norms > 0]
    if M.shape[1] == 0:
        return np.zeros((M.shape[0], 0))
    U, sv, _ = np.linalg.svd(M, full_matrices=False)
    return U[:, sv > rel * sv[0]]


def _separation(QA: np.ndarray, QB: np.ndarray) -> float:
    """Sine of the largest principal angle of span(QA) to span(QB) [-]."""
    if QA.shape[1] == 0:
        return 0.0
    if QB.shape[1] == 0:
        return 1.0
    Rm = QA - QB @ (QB.T @ QA)
    sv = np.linalg.svd(Rm, compute_uv=False)
    return float(min(sv[0], 1.0))


@dataclass(frozen=True, slots=True, kw_only=True)
class Isolability:
    """Which pairs of effect words one log can tell apart (see the module docstring).

    Parameters
    ----------
    words : tuple of str
        Effect words with a candidate on this log, then ``calibration``.
    separation : ndarray, shape (n, n)
        Pair separation in [0, 1], symmetric; the diagonal is 0 [-].
    threshold : float
        Separation at which a pair counts as isolable [-].
    """

    words: tuple[str, ...]
    separation: np.ndarray
    threshold: float = ISOLABILITY_THRESHOLD

    def isolable(self, a: str, b: str) -> bool:
        """True when this log can tell ``a`` from ``b``."""
        i, j = self.words.index(str(a)), self.words.index(str(b))
        return bool(self.separation[i, j] >= self.threshold)

    def confusable_with(self, word: str) -> list[str]:
        """Words this log cannot tell from ``word`` (``calibration`` included)."""
        if str(word) not in self.words:
            return []
        i = self.words.index(str(word))
        return [w for j, w in enumerate(self.words) if j != i and self.separation[i, j] < self.threshold]

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping: ``words``, ``separation`` and ``isolable`` matrices, ``threshold``, ``not_isolable`` pairs."""
        n = len(self.words)
        pairs = [f"{self.words[i]}|{self.words[j]}" for i in range(n) for j in range(i + 1, n)
                 if self.separation[i, j] < self.threshold]
        return {"words": list(self.words), "threshold": self.threshold,
                "separation": [[round(float(x), 4) for x in row] for row in self.separation],
                "isolable": [[bool(i != j and self.separation[i, j] >= self.threshold) for j in range(n)]
                             for i in range(n)],
                "not_isolable": pairs}


def isolability(data: GapData, fits: Sequence[CandidateFit], *, threshold: float = ISOLABILITY_THRESHOLD) -> Isolability:
    """The per-log isolability matrix of the fitted candidates (and the re-calibration).

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    fits : sequence of CandidateFit
        One fit per candidate (their grid optima fix the nonlinear parameters).
    threshold : float
        Separation at which a pair counts as isolable [-].

    Returns
    -------
    Isolability
        Words, separations and the threshold.
    """
    rows = data.stacked(data.held_out)
    C = _design_matrix(_calibration(data), rows)
    QC = _basis(C)
    words: list[str] = []
    bases: list[np.ndarray] = []
    joint: list[np.ndarray] = []
    for fit in fits:
        if fit.structure is None or fit.effect is Effect.NONE:
            continue
        if fit.effect is Effect.TORQUE_GAIN:
            # a gain scales everything the motor does: its signature is the nominal model's own
            # motor torque (J_m theta'' + d_m theta' + tau_s), not the raw command, which also
            # holds whichever effect is present
            explained = data.columns["u"] - data.targets["motor"]
            F = data.stack({"motor": explained})[rows][:, None]
        else:
            F = _design_matrix(fit.structure.coefs, rows)
        words.append(str(fit.effect))
        bases.append(_basis(F))
        joint.append(_basis(np.column_stack([F, C])))
    n = len(words)
    sep = np.zeros((n + 1, n + 1))
    for i in range(n):
        for j in range(i + 1, n):
            sep[i, j] = sep[j, i] = max(_separation(bases[i], joint[j]), _separation(bases[j], joint[i]))
        # against the re-calibration alone: how much of the effect's features lies outside it
        sep[i, n] = sep[n, i] = _separation(bases[i], QC)
    return Isolability(words=tuple(words) + (CALIBRATION,), separation=sep, threshold=threshold)
