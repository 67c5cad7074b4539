"""The simulated encoder chain: from the motor's increments to the position the NC reads.

    ActPos = sign * count * AxisEncoderScalingFactor + AxisEncoderOffset,   sign = -1 if AxisEncoderDirectionInverse
    count  = increments + base   (the NC's software counter: it starts at ``increments & AxisEncoderEncoderMask``
                                  and counts on over the hardware counter's overflow)

(Beckhoff: Infosys TF50x0 NC PTP "Encoder Evaluation", https://infosys.beckhoff.com/content/1033/tf50x0_tc3_nc_ptp/3439907723.html:
the scaling factor turns increments into axis units, the position bias is added, "Invert Encoder Counting Direction"
reverses the count; the ADS encoder parameters 0x06/0x07/0x08/0x15,
https://infosys.beckhoff.com/content/1033/tc3_ads_intro/713102219.html: "Writing is not allowed if the controller
enable has been issued", which the NC's parameter table enforces (0x4B42).)

The motor's ``increments`` are what is physical: a parameter change does not move the motor, so the same
increments give another ActPos (the NC sees its position jump without motion: ``NcCore`` restarts what keeps
a position history, see ``NcCore.position_jump_hooks``). The hardware counter holds ``increments & mask``; the
NC's count goes on across its overflow, so ActPos stays continuous while the axis moves. Writing the mask
re-reads the encoder: the count restarts at ``increments & mask`` (the position jumps by whole overflows).

Decisions where Beckhoff is silent: the increments are not rounded (a simulation has no quantisation; ``&`` of
a fractional count is its remainder modulo mask + 1); the chain is affine, so the drive keeps its state as a
position and the lag of the position controller is the same whether taken in increments or in units: the chain
costs nothing per cycle, only when a parameter changes (:meth:`EncoderChain.configure`).

It may import: numpy, nc_server.core.params (the parameter names).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..core.params import AxisParams


class EncoderChain:
    """The encoder chains of all axes (columns indexed like the drive's axes).

    Attributes:
        scaling: AxisEncoderScalingFactor [u/inc].
        offset: AxisEncoderOffset [u].
        sign: -1.0 where AxisEncoderDirectionInverse, else +1.0.
        period: AxisEncoderEncoderMask + 1 [inc] (the hardware counter's range).
        base: count - increments [inc]: 0 until the mask is written.
    """

    def __init__(self, n: int) -> None:
        self.scaling = np.ones(n)
        self.offset = np.zeros(n)
        self.sign = np.ones(n)
        self.period = np.full(n, 2.0 ** 32)
        self.base = np.zeros(n)
        #: every axis's chain is the identity (scaling 1, offset 0, sign +1, base 0; set by :meth:`configure`):
        #: the vectorized conversions take one operation instead of four, bit for bit the same
        self.identity = True

    def position(self, i: int, increments: float) -> float:
        """ActPos [u] of axis ``i`` at the motor's ``increments``."""
        return float(self.sign[i] * (increments + self.base[i]) * self.scaling[i] + self.offset[i])

    def increments(self, i: int, position: float) -> float:
        """The motor's increments [inc] at which axis ``i`` reads ``position`` [u] (the chain's inverse)."""
        return float((position - self.offset[i]) / self.scaling[i] * self.sign[i] - self.base[i])

    def positions(self, increments: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """ActPos [u] of the axes ``rows`` at their motors' ``increments`` (:meth:`position`, vectorized)."""
        if self.identity:  # 1 * (x + 0) * 1 + 0 is x + 0 (-0 becomes +0 there too): a new array, the same bits
            return np.add(increments, 0.0)
        return self.sign[rows] * (increments + self.base[rows]) * self.scaling[rows] + self.offset[rows]

    def increments_at(self, positions: np.ndarray) -> np.ndarray:
        """The increments [inc] at which every axis reads ``positions`` [u] (:meth:`increments`, vectorized)."""
        if self.identity:  # (x - 0) / 1 * 1 - 0 is x, bit for bit (also -0): a new array
            return np.array(positions, dtype=np.float64)
        return (positions - self.offset) / self.scaling * self.sign - self.base

    def velocities(self, velocity: np.ndarray) -> np.ndarray:
        """Axis velocities [u/s] of motor velocities [inc/s] (``velocity * scaling * sign``; a new array)."""
        if self.identity:  # (x * 1 * 1 is x, bit for bit)
            return np.array(velocity, dtype=np.float64)
        return velocity * self.scaling * self.sign

    def inc_velocities(self, velocity: np.ndarray) -> np.ndarray:
        """Motor velocities [inc/s] of axis velocities [u/s] (``velocity / scaling * sign``; a new array)."""
        if self.identity:  # (x / 1 * 1 is x, bit for bit)
            return np.array(velocity, dtype=np.float64)
        return velocity / self.scaling * self.sign

    def hardware_count(self, i: int, position: float) -> float:
        """What the encoder's hardware counter holds at ``position`` [u]: increments & mask [inc] (not rounded)."""
        return float(np.mod(self.increments(i, position), self.period[i]))

    def configure(self, i: int, params: AxisParams, position: float) -> float:
        """Take axis ``i``'s encoder parameters; return its position [u] after the change.

        The motor stands where it is (its increments are kept); a new mask restarts the count at
        ``increments & mask``. Without a change of the chain ``position`` comes back unchanged (bit for bit).
        """
        scaling, offset = float(params.AxisEncoderScalingFactor), float(params.AxisEncoderOffset)
        sign = -1.0 if params.AxisEncoderDirectionInverse else 1.0
        period = float(params.AxisEncoderEncoderMask) + 1.0
        if (scaling, offset, sign, period) == (self.scaling[i], self.offset[i], self.sign[i], self.period[i]):
            return position
        inc = self.increments(i, position)
        if period != self.period[i]:  # the encoder is read anew: the count restarts at increments & mask
            self.base[i] = float(np.mod(inc, period)) - inc
            self.period[i] = period
        self.scaling[i], self.offset[i], self.sign[i] = scaling, offset, sign
        self.identity = bool(np.all(self.scaling == 1.0) and np.all(self.offset == 0.0) and np.all(self.sign == 1.0)
                             and np.all(self.base == 0.0))
        return self.position(i, inc)


def pulse_passed(a: np.ndarray, b: np.ndarray, spacing: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """The encoder's index (sync) pulses at ``offset + k * spacing``: per axis the last one passed moving from ``a``
    to ``b``, NaN where none was. A pulse exactly at ``a`` does not count (it was passed in the cycle before), one
    exactly at ``b`` does. Any consistent unit (SimDrive: axis units; the CiA 402 device: increments).

    The one crossing rule of the simulated drives: ``SimDrive.latch_sync_pulse`` and ``Cia402Device``'s touch probe.
    """
    fa, fb = (a - offset) / spacing, (b - offset) / spacing
    up = fb > fa
    k = np.where(up, np.floor(fb), np.ceil(fb))  # the last pulse index reached in the direction of travel
    crossed = np.where(up, k > fa, k < fa) & (fa != fb)
    return np.where(crossed, offset + k * spacing, np.nan)


def build(params: Sequence[AxisParams]) -> EncoderChain:
    """An encoder chain for ``params``, each axis's motor at 0 increments (ActPos = AxisEncoderOffset)."""
    chain = EncoderChain(len(params))
    for i, p in enumerate(params):
        chain.configure(i, p, 0.0)
    return chain
