"""Recorded samples and their accounting: the SAMPLE record, loss bookkeeping in bounded memory, sequence checks.

Split from :mod:`forecast_design.runtime.protocol` (which re-exports every name here): the
protocol encodes and parses frames, this module keeps what a run received. Pure Python, no
serial port, no numpy.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, fields

from ..errors import ParameterError

__all__ = ["MAX_RUN_SAMPLES", "Sample", "SampleTracker", "SequenceCounter"]


@dataclass(frozen=True, slots=True)
class Sample:
    """One recorded sample as streamed by the board (float32 on the wire).

    Parameters
    ----------
    index : int
        Sample number since START, from 0 [-].
    t : float
        Board time [s].
    tau_m : float
        Motor torque command applied over [t, t + 1/rate) [N m].
    theta : float
        Motor angle [rad].
    q : float
        Environment/joint angle [rad].
    tau_s : float
        Spring torque [N m].
    tau_r : float
        Force reference [N m].
    u : float
        Force controller output [N m] (tau_m = sat(u + tau_frc_hat)).
    tau_frc_hat : float
        Friction estimate fed forward [N m] (0 for compensator none).
    """

    index: int
    t: float
    tau_m: float
    theta: float
    q: float
    tau_s: float
    tau_r: float
    u: float
    tau_frc_hat: float


#: Most samples one run may request: 2**24, 2.3 h at 2 kHz. The recorder keeps 8 bytes per value
#: (index and each float field) and one validity byte per sample, so its memory is bounded by this.
MAX_RUN_SAMPLES = 1 << 24


def _finite(x: float) -> bool:
    return math.isfinite(x)


class SampleTracker:
    """Loss accounting over the sample indices received, in bounded memory.

    Samples must arrive with strictly increasing indices; a gap is counted
    as lost (by index), a repeated or older index as out of order and kept
    out of the record, an index at or beyond ``n_expected`` (the count
    requested at START) as out of range and dropped, and a sample carrying
    a NaN or an infinity is kept as *invalid* (its row is interpolated and
    flagged). Nothing is dropped silently: every case has its counter.

    The record is columnar (``array`` of float64 per field), so memory is
    at most ``n_expected`` x (8 x (fields) + 1) bytes.

    Parameters
    ----------
    n_expected : int, optional
        Samples requested at START, at most :data:`MAX_RUN_SAMPLES`; indices
        at or above it are out of range. None: no upper bound (tests).

    Attributes
    ----------
    lost : list of tuple of int
        Half-open ranges ``(first, stop)`` of missing indices.
    out_of_order : int
        Samples rejected for a non-increasing index.
    out_of_range : int
        Samples rejected for an index >= ``n_expected``.
    invalid : int
        Samples kept but carrying a non-finite value.
    """

    def __init__(self, n_expected: int | None = None) -> None:
        if n_expected is not None and not 0 <= int(n_expected) <= MAX_RUN_SAMPLES:
            raise ParameterError(f"a run records 0 .. {MAX_RUN_SAMPLES} samples, got {n_expected}",
                                 name="n_expected", value=n_expected)
        self.n_expected = None if n_expected is None else int(n_expected)
        self._fields = tuple(f.name for f in fields(Sample) if f.name != "index")
        self._index = array("q")
        self._values = {name: array("d") for name in self._fields}
        self._valid = array("b")
        self.lost: list[tuple[int, int]] = []
        self.out_of_order = 0
        self.out_of_range = 0
        self.invalid = 0

    @property
    def next_index(self) -> int:
        """Index expected next [-]."""
        return self._index[-1] + 1 if self._index else 0

    @property
    def received(self) -> int:
        """Samples accepted (valid or not) [-]."""
        return len(self._index)

    def add(self, sample: Sample) -> None:
        """Record one received sample (see the class docstring for what is counted)."""
        index = int(sample.index)
        if self.n_expected is not None and index >= self.n_expected:
            self.out_of_range += 1
            return
        expected = self.next_index
        if index < expected:
            self.out_of_order += 1
            return
        if index > expected:
            self.lost.append((expected, index))
        values = [float(getattr(sample, name)) for name in self._fields]
        ok = all(map(_finite, values))
        self.invalid += not ok
        self._index.append(index)
        for name, v in zip(self._fields, values):
            self._values[name].append(v)
        self._valid.append(1 if ok else 0)

    def finish(self, n_expected: int) -> None:
        """Count the missing tail once the run is over (``n_expected`` samples were due)."""
        if self.next_index < n_expected:
            self.lost.append((self.next_index, n_expected))

    @property
    def n_lost(self) -> int:
        """Number of lost samples [-]."""
        return sum(stop - first for first, stop in self.lost)

    @property
    def indices(self) -> array:
        """Indices of the accepted samples, strictly increasing."""
        return self._index

    @property
    def valid(self) -> array:
        """1 where the accepted sample's values are all finite, else 0."""
        return self._valid

    def column(self, name: str) -> array:
        """Values of field ``name`` of the accepted samples (float64)."""
        return self._values[name]

    @property
    def samples(self) -> list[Sample]:
        """The accepted samples as :class:`Sample` objects (a copy; for small records)."""
        cols = [self._values[name] for name in self._fields]
        return [Sample(i, *(c[k] for c in cols)) for k, i in enumerate(self._index)]


@dataclass(slots=True)
class SequenceCounter:
    """Checks a sender's frame sequence numbers (+1 per frame, modulo 65536).

    Attributes
    ----------
    skipped : int
        Sequence numbers never seen between two frames received (frames lost
        whole or rejected by the CRC) [-].
    repeated : int
        Frames whose sequence number repeats or goes back (a duplicated or
        replayed frame, or a sender restart) [-].
    """

    skipped: int = 0
    repeated: int = 0
    last: int | None = None

    def note(self, seq: int) -> None:
        """Account for one intact frame's sequence number."""
        seq &= 0xFFFF
        if self.last is None:
            self.last = seq
            return
        step = (seq - self.last) & 0xFFFF
        if step == 0 or step >= 0x8000:
            self.repeated += 1
            if step == 0:
                return
        else:
            self.skipped += step - 1
        self.last = seq
