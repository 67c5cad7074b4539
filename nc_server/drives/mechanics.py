"""The simulated drive's mechanics: the motor torque its motion takes, in % of the rated torque (as TwinCAT shows
NCTOPLC SetTorque / ActTorque).

    torque [N*m] = SimLoadInertia * a + SimViscousFriction * v + SimCoulombFriction * sign(v)
    torque [%]   = 100 * torque [N*m] / SimRatedTorque

* SetTorque: of the set-point (SetVelo, SetAcc) plus TorqueOffset; ActTorque: of the measured motion (ActVelo,
  ActAcc). SetTorqueDerivative / ActTorqueDerivative: their change per second [%/s] (the difference of two
  cycles over the cycle time).
* TorqueOffset: PLCTONC.ExtTorque [%], the additive torque the PLC asks for (:attr:`Mechanics.offset`, set by
  the NC when a PLCTONC arrives: a non-finite value keeps the last one, |value| is clipped to 1000 %).

Decisions (the manual is silent): Coulomb friction as sign(v) (0 at rest: a standing axis needs no torque); the
additive torque shows in SetTorque only (the model's motion is the position controller's, which the torque
does not change: the model never limits the motion, it reports what the motion takes); a drive that delivers
no torque (controller disabled, drive not ready or faulted, invalid I/O data) shows 0 in every torque field,
TorqueOffset included; defaults 1e-4 N*m*s^2/u, 1e-4 N*m*s/u, 0.02 N*m, 1 N*m (a small servo: 1000 u/s
takes 12 % of its rated torque against friction).

Cost: a few vector operations per cycle for all axes at once; while no drive delivers torque the model rests
after two steps (the fields fall to 0, then their derivatives) and does no numpy work at all. The CiA 402 drive's
set-point rows (:meth:`Mechanics.step_set`) are not computed again while their inputs stay (e.g. every axis at a
constant velocity): they would come out the same.

It may import: numpy, nc_server.core.params, nc_server.drives.npcount.
"""
from __future__ import annotations

import numpy as np

from ..core.params import AxisParams
from .npcount import count_nonzero

#: |TorqueOffset| at most this [%] (a PLC value beyond is clipped, as a drive limits its additive torque)
OFFSET_LIMIT = 1000.0



def _add_friction(t: np.ndarray, v: np.ndarray, tmp: np.ndarray, viscous: np.ndarray, coulomb: np.ndarray) -> None:
    """``t += viscous * v`` then ``t += coulomb * sign(v)``, in place through ``tmp`` (the model's friction terms:
    the same operations in the same order wherever a row is computed, so rows agree bit for bit)."""
    np.multiply(v, viscous, tmp)
    t += tmp
    np.sign(v, tmp)
    tmp *= coulomb
    t += tmp

class Mechanics:
    """Torques of all axes (columns indexed like the drive's axes).

    Attributes:
        offset: the additive torque per axis [%] (PLCTONC.ExtTorque as applied).
        fields: (6, n): rows SetTorque, ActTorque, ActTorqueDerivative, SetTorqueDerivative, AbsPhasingPos
            (always 0), TorqueOffset -- the order of their NCTOPLC offsets 136, 144 and 192..216 [% and %/s].
    """

    def __init__(self, n: int, cycle_time: float) -> None:
        self.inv_dt = 1.0 / float(cycle_time)
        self._inv_dt0 = np.array(self.inv_dt)  # (0-d: an operation with a Python float converts it each call)
        self.inertia = np.zeros(n)   # [% s^2/u]: already scaled by 100 / SimRatedTorque
        self.viscous = np.zeros(n)   # [% s/u]
        self.coulomb = np.zeros(n)   # [%]
        self.offset = np.zeros(n)
        self.fields = np.zeros((6, n))
        self._n = n
        self._offset_on = False  # some offset is not 0 (else the offset's rows need no work)
        self._offset_dirty = False  # the offsets changed since the last step
        self._rest = 0  # steps in a row without any drive delivering torque (3: at rest, nothing to do)
        self._v = np.zeros((2, n))  # step's work rows: velocities (set, act), torques, one term
        self._t = np.zeros((2, n))
        self._tmp = np.zeros((2, n))
        # (the views step uses, made once: a slice per use costs more than the operation on a few axes)
        f, t = self.fields, self._t
        self._f01, self._f10, self._f23, self._t_rev = f[0:2], f[1::-1], f[2:4], t[::-1]
        self._v0, self._v1, self._t0, self._t1, self._f5 = self._v[0], self._v[1], t[0], t[1], f[5]
        self._f1, self._tmp1 = f[1], self._tmp[1]
        self._f0, self._f3, self._tmp0 = f[0], f[3], self._tmp[0]
        # step_set's inputs (bytes of the set velocities, accelerations, delivering masks) of its last computation,
        # and whether that one had the same inputs as the one before (then rows 0, 3 and 5 hold their steady values)
        self._set_key: tuple[bytes, bytes, bytes] = (b"", b"", b"")
        self._set_same = False
        #: counts the steps that (may have) written rows 0, 3, 4 or 5 of :attr:`fields` (SetTorque, its derivative,
        #: AbsPhasingPos, TorqueOffset): while it stays, those rows hold the values a reader copied last (the
        #: output packer copies rows 1 and 2 alone then)
        self.set_version = 0

    def configure(self, i: int, params: AxisParams) -> None:
        self._set_key = (b"", b"", b"")  # (step_set computes anew)
        k = 100.0 / float(params.SimRatedTorque)
        self.inertia[i] = float(params.SimLoadInertia) * k
        self.viscous[i] = float(params.SimViscousFriction) * k
        self.coulomb[i] = float(params.SimCoulombFriction) * k

    def set_offset(self, values: np.ndarray) -> None:
        """The additive torque [%] per axis: non-finite values keep the last value, |value| clipped to 1000 %."""
        ok = np.isfinite(values)
        self.offset[ok] = np.clip(values[ok], -OFFSET_LIMIT, OFFSET_LIMIT)
        self._offset_on = bool(count_nonzero(self.offset))
        self._offset_dirty = True

    @property
    def resting(self) -> bool:
        """No drive delivers torque and every field was 0 in the last step already (nothing to copy)."""
        return self._rest >= 3

    def step_set(self, delivering: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        """:meth:`step` for a caller that writes ActTorque and ActTorqueDerivative (rows 1 and 2) itself after every
        step that did work (the CiA 402 drive: ActTorque is the drive's 0x6077): the other rows and
        :attr:`resting` as :meth:`step` leaves them, bit for bit; rows 1 and 2 as the caller wrote them (at rest as
        :meth:`step` leaves them).

        A step with the same inputs (compared by their bytes: float64 set-points, a bool mask) as the two before it
        does nothing: rows 0, 3 and 5 already hold what it would write (the torque computed anew bit for bit the
        same, its derivative ``(t - t) * inv_dt`` the same as last time, the offset's row too). So the model's
        parameters change through :meth:`configure` and :meth:`set_offset` only, which make the next step compute."""
        k = count_nonzero(delivering)
        if not k:
            self._set_key = (b"", b"", b"")
            self.step(delivering, set_velo, set_acc, set_velo, set_acc)  # (the rest: no model rows needed)
            return
        key = (set_velo.tobytes(), set_acc.tobytes(), delivering.tobytes())
        if self._offset_dirty:
            same = False
        else:
            last = self._set_key
            same = key[0] == last[0] and key[1] == last[1] and key[2] == last[2]
            if same and self._set_same:  # (the steady cycle, e.g. a constant velocity: nothing changes)
                return
        self._set_key, self._set_same = key, same
        self._rest = 0
        self.set_version += 1
        f0, t0, tmp = self._f0, self._t0, self._tmp0
        np.multiply(set_acc, self.inertia, t0)  # (the operations of step's row 0, in its order)
        _add_friction(t0, set_velo, tmp, self.viscous, self.coulomb)
        if self._offset_on:
            t0 += self.offset
        if k < self._n:
            t0 *= delivering
        f3 = self._f3
        np.subtract(t0, f0, f3)
        f3 *= self._inv_dt0
        f0[...] = t0
        if self._offset_on or self._offset_dirty:
            np.multiply(self.offset, delivering, out=self._f5)
            self._offset_dirty = False

    def step_actual(self, delivering: np.ndarray, act_velo: np.ndarray, act_acc: np.ndarray,
                    k: int | None = None) -> None:
        """:meth:`step` for a user of ActTorque alone (the simulated CiA 402 drive's 0x6077): row 1 of
        :attr:`fields` as :meth:`step` computes it, bit for bit, and :attr:`resting`; the other rows are not kept
        (at 0, or what an earlier :meth:`step` left). ``k``: the number of delivering axes, if the caller knows it."""
        f1 = self._f1
        if k is None:
            k = count_nonzero(delivering)
        if not k:
            if self._rest < 3:
                self._rest += 1
                if self._rest < 3:
                    f1[...] = 0.0
            return
        self._rest = 0
        tmp = self._tmp1
        np.multiply(act_acc, self.inertia, f1)  # (the operations of step's row 1, in its order)
        _add_friction(f1, act_velo, tmp, self.viscous, self.coulomb)
        if k < self._n:
            f1 *= delivering

    def step(self, delivering: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray,
             act_velo: np.ndarray, act_acc: np.ndarray) -> None:
        """This cycle's torques from the set-point and the measured motion.

        Args:
            delivering: bool per axis: the drive delivers torque (enabled, ready, valid I/O).
            set_velo, set_acc: the set-point [u/s, u/s^2]; act_velo, act_acc: the measured motion.
        """
        f = self.fields
        k = count_nonzero(delivering)  # (far cheaper than ndarray.any here)
        if not k:
            if self._rest < 3:
                self._rest += 1
                self.set_version += 1
                if self._rest < 3:  # 1: the fields fall to 0 within this cycle, 2: their derivatives
                    f[2:4] = f[1::-1] * -self.inv_dt
                    f[[0, 1, 5]] = 0.0
            return
        self._rest = 0
        self.set_version += 1
        # (into preallocated rows: the same operations on the same values as
        # inertia * acc + viscous * v + coulomb * sign(v), without a new array per term)
        v, t, tmp = self._v, self._t, self._tmp
        np.copyto(self._v0, set_velo)
        np.copyto(self._v1, act_velo)
        inertia = self.inertia
        np.multiply(set_acc, inertia, out=self._t0)  # (the same products as a copy multiplied in place)
        np.multiply(act_acc, inertia, out=self._t1)
        _add_friction(t, v, tmp, self.viscous, self.coulomb)
        if self._offset_on:
            self._t0 += self.offset
        if k < self._n:
            t *= delivering
        # derivatives from the values shown last cycle (rows 0, 1), in NCTOPLC's order (act, set)
        f23 = self._f23
        np.subtract(self._t_rev, self._f10, out=f23)
        f23 *= self._inv_dt0
        np.copyto(self._f01, t)
        if self._offset_on or self._offset_dirty:
            np.multiply(self.offset, delivering, out=self._f5)
            self._offset_dirty = False
