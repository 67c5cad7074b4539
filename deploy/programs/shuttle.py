"""A shuttle for the deploy/ PLC programs: one axis powered and moved between two positions.

Used by ``plc1.py`` and ``plc2.py`` (plc-run puts the program's folder on ``sys.path``). Only the
public block API (``MC_Power``, ``MC_MoveAbsolute``, ``MC_Reset``) and the axis's own data (``Axis.Status``,
``Axis.NcToPlc``: the axis is bound when plc-run loads the program). What a shuttle does each cycle:

* ``MC_Power`` with Enable TRUE: claims the axis and keeps it enabled (the block re-claims by itself
  after a loss of the NC or of the link).
* Once ``power.Status`` is TRUE and the dwell is over, one ``MC_MoveAbsolute`` to the other end (a
  rising edge of Execute: a new command, never a replay). Done -> dwell, then the way back.
* CommandAborted (another client's newer command took the axis) -> dwell, then a new move.
* An error of the move (0x4B0F NC data stale, 0x745 no reply, an axis error, ...), or an axis
  error while idle (e.g. 0x8F02 after a lost link; only the holder resets) -> the program waits
  ``rearm`` seconds, runs ``MC_Reset``, and only then moves again. MC_Power's Error/ErrorID show
  its own errors and the axis's (TcMC 4.1): both are logged as ``error 0x... (MC_Power)``.

Every event is one line on stdout (``docker logs``): ``<client> <unix time> <nc>:<axis> <event> ...``;
tests across hosts read ``move ->`` (a command issued), ``error 0x....`` and ``power on/off``.
"""
from __future__ import annotations

import os
import time

from plc_client import AXIS_REF, MC_MoveAbsolute, MC_Power, MC_Reset

CLIENT = os.environ.get("ZNC_ID", "plc")


def env_float(name: str, default: float) -> float:
    """A float from the environment (``default`` when unset or not a number)."""
    try:
        return float(os.environ.get(name, default))
    except ValueError:
        return default


def say(axis: AXIS_REF, event: str) -> None:
    """One event line on stdout."""
    print(f"{CLIENT} {time.time():.3f} {axis.nc}:{axis.axis_id} {event}", flush=True)


class Shuttle:
    """Axis ``axis`` between ``a`` and ``b`` [u] at ``velocity`` [u/s], ``dwell`` [s] at each end.

    With ``power=False`` the shuttle only commands moves (the axis is claimed and supplied by
    another client: arbitration lets any operator command it).
    """

    def __init__(self, axis: AXIS_REF, a: float, b: float, velocity: float, dwell: float = 0.5,
                 power: bool = True, rearm: float | None = None) -> None:
        self.axis, self.a, self.b, self.velocity, self.dwell = axis, a, b, velocity, dwell
        self.rearm = env_float("ZNC_REARM_S", 2.0) if rearm is None else rearm
        self.use_power = power
        self.power, self.move, self.reset = MC_Power(), MC_MoveAbsolute(), MC_Reset()
        self.target = b
        self.state = "idle"
        self.hold_until = 0.0
        self._status = False
        self._power_err = 0

    def ready(self) -> bool:
        """The axis can take a move: powered by this shuttle, or (without power) data valid and enabled."""
        if self.use_power:
            return bool(self.power.Status)
        st = self.axis.Status
        return st.Valid and not st.ErrorStop and bool(self.axis.NcToPlc.StateDWord & (1 << 20))

    def axis_error(self) -> bool:
        """The NC reports an axis error (on valid data)."""
        ax = self.axis
        return ax.Status.Valid and bool(ax.NcToPlc.StateDWord & (1 << 31))

    def cycle(self, now: float) -> None:
        """Run the blocks of one PLC cycle (``now`` = plc.now [s])."""
        ax = self.axis
        if self.use_power:
            self.power(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True)
            if bool(self.power.Status) != self._status:
                self._status = bool(self.power.Status)
                say(ax, "power on" if self._status else "power off")
            err = int(self.power.ErrorID) if self.power.Error else 0
            if err != self._power_err:
                self._power_err = err
                if err:
                    say(ax, f"error 0x{err:X} (MC_Power)")
        if self.state == "idle" and self.use_power and self.power.Active and self.axis_error():
            # an axis error (e.g. 0x8F02 after a lost link): the holder resets it, then moves again
            say(ax, f"axis error 0x{ax.NcToPlc.ErrorCode:X}; reset in {self.rearm:g} s")
            self._next("reset", now + self.rearm)
        elif self.state == "idle":
            if now >= self.hold_until and self.ready():
                say(ax, f"move -> {self.target:.3f}")
                self.move(Axis=ax, Execute=True, Position=self.target, Velocity=self.velocity)
                self.state = "moving"
        elif self.state == "moving":
            self.move(Axis=ax, Execute=True)
            if self.move.Done:
                say(ax, f"done at {ax.NcToPlc.ActPos:.3f}")
                self.target = self.a if self.target == self.b else self.b
                self._next("idle", now + self.dwell)
            elif self.move.CommandAborted:
                say(ax, "aborted (a newer command took the axis)")
                self._next("idle", now + self.dwell)
            elif self.move.Error:
                say(ax, f"error 0x{int(self.move.ErrorID):X} (MC_MoveAbsolute); reset in {self.rearm:g} s")
                self._next("reset", now + self.rearm)
        elif self.state == "reset" and now >= self.hold_until:
            self.reset(Axis=ax, Execute=True)
            if self.reset.Done or self.reset.Error:
                if self.reset.Error:
                    say(ax, f"reset error 0x{int(self.reset.ErrorID):X}")
                self.reset(Execute=False)
                self._next("idle", now + self.dwell)

    def _next(self, state: str, hold_until: float) -> None:
        self.move(Execute=False)  # the next move is a rising edge, a new command
        self.state, self.hold_until = state, hold_until
