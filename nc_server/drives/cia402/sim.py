"""The ``cia402-sim`` backend: simulated CiA 402 drives in the NC's process, exchanged with zero latency.

:class:`LocalLink` steps a :class:`.device.Cia402Device` with each cycle's outputs and returns its inputs at once
(age 0, alive). :class:`Cia402SimDrive` is a :class:`.drive.Cia402Drive` over it with the axes' parameters: it
behaves like ``SimDrive`` (the same first-order lag, encoder chain and mechanics) plus the CiA 402 power state
machine, drive faults and the touch probe latch of the index pulses.

Decisions: at power up the device is in Switch on disabled and the first exchange (at construction) takes it to
Ready to switch on, so an NC enable reaches Operation enabled in the same cycle (MC_Power.Status shows it only
then). Injectable states for tests as ``SimDrive`` has them: :meth:`Cia402SimDrive.set_io_invalid` (the link
stops carrying the axis: its outputs do not reach the device, its inputs stay the last and are invalid at once,
``age`` past ``max_age``, as with a bad EtherCAT WcState) and
:meth:`Cia402SimDrive.set_device_error` (a persistent hardware fault 0x5000 of the device: the drive stops on its
quick-stop ramp and goes to Fault; clearing it lets the next MC_Reset acknowledge it -- unlike ``SimDrive``,
where the error vanished by itself), plus :meth:`Cia402SimDrive.inject_fault` and :meth:`Cia402SimDrive.set_silent`
(lost communication), and the simulated stepper terminal of ``SimStepper`` axes (:mod:`..stepper`, the same model
as ``SimDrive``'s: SimStall makes the device's motor stand, SimTerminalError sets the status word).

It may import: numpy, nc_server.core.params, nc_server.drives.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ...core.params import AxisParams, ConfigError
from ..base import DriveContext
from ..stepper import StepperTerminals
from .device import HARDWARE_ERROR_CODE, Cia402Device
from .drive import DEFAULT_KV, Cia402Drive, link_options, reaction_margin_option
from .drive import axis_options as axis_options_of
from .image import ProcessDataLink, RxImage, TxImage
from .objects import Mode


class LocalLink(ProcessDataLink):
    """In process, zero latency: :meth:`exchange` steps the device with the outputs and returns its inputs.

    Attributes:
        device: the simulated drives.
        invalid: per axis, the link does not carry this axis (its inputs stay, their age grows).
        alive: per axis, the node answers (False: ``alive`` False in the inputs: lost communication).
        invalid_age: the least age an invalid axis's inputs report (``Cia402SimDrive``: ``max_age + 1``, so the
            data are invalid at once, as a bad EtherCAT WcState makes them; 1: they age cycle by cycle).
    """

    def __init__(self, device: Cia402Device) -> None:
        self.device = device
        self.n = device.n
        self.invalid = np.zeros(self.n, dtype=bool)
        self.alive = np.ones(self.n, dtype=bool)
        self.invalid_age = 1
        self._last_rx: RxImage | None = None
        self._last_tx: TxImage | None = None
        self._degraded = False
        #: the caller never writes the arrays of an RxImage after its exchange (:class:`Cia402SimDrive`'s drive):
        #: the device keeps them (no copies; an unchanged probe function is the same array, no comparison)
        self.owned = False

    def degraded_changed(self) -> None:
        self._degraded = bool(self.invalid.any() or not self.alive.all())

    def peek(self) -> TxImage:
        """The device's inputs of its last step (an axis the link does not carry: the last it carried)."""
        return self._last_tx if self._degraded and self._last_tx is not None else self.device.tx

    def exchange(self, rx: RxImage) -> TxImage:
        if not self._degraded:
            tx = self.device.step(rx, self.owned)
            self._last_rx, self._last_tx = rx, tx
            return tx
        last_rx, last_tx = self._last_rx or rx, self._last_tx or self.device.tx
        bad = self.invalid | ~self.alive
        if bad.all():
            tx = self.device.step(None)  # nothing reaches the drives
        else:
            keep = {f: np.where(bad, getattr(last_rx, f), getattr(rx, f)) for f in
                    ("controlword", "mode", "target_position", "target_velocity", "probe_function")}
            tx = self.device.step(RxImage(cycle=rx.cycle, **keep))
        out = TxImage(**{f: np.where(bad, getattr(last_tx, f), getattr(tx, f)).astype(getattr(tx, f).dtype)
                         for f in ("statusword", "mode_display", "position_actual", "velocity_actual",
                                   "torque_actual", "error_code", "probe_status", "probe_position", "probe2_pos",
                                   "probe2_neg", "rx_cycle")},
                      age=np.where(bad, np.maximum(last_tx.age + 1, self.invalid_age), 0), alive=self.alive.copy())
        self._last_rx = RxImage(cycle=rx.cycle, **{f: np.where(bad, getattr(last_rx, f), getattr(rx, f)) for f in
                                                  ("controlword", "mode", "target_position", "target_velocity",
                                                   "probe_function")})
        self._last_tx = out
        return out


class Cia402SimDrive(Cia402Drive):
    """Simulated CiA 402 drives in process (the ``cia402-sim`` backend).

    Attributes:
        device: the simulated drives behind the link.
    """

    def __init__(self, params: Sequence[AxisParams], cycle_time: float, *, mode: Mode | Sequence[Mode] = Mode.CSP,
                 kv: float | Sequence[float] = DEFAULT_KV, max_age: int = 3, reaction_margin: int = 0) -> None:
        self.device = Cia402Device(len(params), cycle_time)  # (configured by Cia402Drive.__init__)
        self.terminals = StepperTerminals(len(params))  # SimStepper axes: the motor stalls in the device
        self._local = LocalLink(self.device)
        super().__init__(params, cycle_time, self._local, simulated=True, mode=mode, kv=kv, max_age=max_age,
                         reaction_margin=reaction_margin)
        self._local.invalid_age = self.max_age + 1
        self._local.owned = True  # (Cia402Drive makes new arrays for each RxImage, or passes ones it never writes)

    @classmethod
    def from_config(cls, params: Sequence[AxisParams], cycle_time: float,
                    axis_options: Sequence[Mapping[str, Any]], context: DriveContext) -> Cia402SimDrive:
        """Per axis ``mode`` ("csp"/"csv") and ``kv`` (:func:`.drive.axis_options`); ``[drives.cia402-sim]``
        ``max_age`` (:func:`.drive.link_options`) and ``reaction_margin`` (default 0).

        Raises:
            ConfigError: an unknown option or a bad value.
        """
        modes, kvs = [], []
        for i, opts in enumerate(axis_options):
            mode, kv, rest = axis_options_of(opts, f"axis[{i}].Drive")
            if rest:
                raise ConfigError(f"axis[{i}].Drive", f"the cia402-sim backend takes mode and kv, got "
                                                      f"{', '.join(sorted(rest))}")
            modes.append(mode)
            kvs.append(kv)
        max_age, rest = link_options(context.options, "drives.cia402-sim")
        margin, rest = reaction_margin_option(rest, "drives.cia402-sim", 0)
        if rest:
            raise ConfigError("drives.cia402-sim", f"the cia402-sim backend takes max_age and reaction_margin, got "
                                                   f"{', '.join(sorted(rest))}")
        n = len(params)
        return cls(params, cycle_time, mode=modes or [Mode.CSP] * n, kv=kvs or [DEFAULT_KV] * n, max_age=max_age,
                   reaction_margin=margin)

    def configure(self, index: int, params: AxisParams) -> None:
        super().configure(index, params)
        if hasattr(self, "device"):
            self.device.configure(index, params)
            self.terminals.configure(index, params)

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        t = self.terminals
        if t.any:  # the stepper terminals (as SimDrive's): a stalled motor stands in the device
            t.update(enabled, set_velo)
            self.device.stalled = t.stalled if t.stalled.any() else None
        super().step(enabled, set_pos, set_velo, set_acc)

    # -- the simulated stepper terminal (MC_PowerStepper; :mod:`..stepper`) ------------------------------------

    def terminal_status(self) -> np.ndarray | None:
        """NCJOBS DriveStatus of every axis; None without SimStepper axes."""
        return self.terminals.status if self.terminals.any else None

    def set_stall(self, index: int, stall: bool) -> None:
        """Stall the stepper of axis ``index`` now: the device's motor stands until the stall is lifted or the set
        velocity is 0 (NotImplementedError: not a SimStepper, 0x4251)."""
        self.terminals.set_stall(index, stall)

    def set_terminal_error(self, index: int, status_word: int) -> None:
        """The error bits of axis ``index``'s terminal status word (:meth:`..stepper.StepperTerminals.set_terminal_error`)."""
        self.terminals.set_terminal_error(index, status_word)

    def set_io_invalid(self, index: int, invalid: bool) -> None:
        """Axis ``index``'s I/O data become invalid (``invalid`` False: valid again) from the next step, as with a bad
        EtherCAT WcState: the link does not carry it (its outputs do not reach the drive, its inputs stay the last)
        and their age is past ``max_age`` at once."""
        self._check_index(index)
        self._local.invalid[index] = bool(invalid)
        self._local.degraded_changed()

    def set_silent(self, index: int, silent: bool) -> None:
        """Axis ``index``'s node stops answering (``alive`` False: lost communication) or answers again."""
        self._check_index(index)
        self._local.alive[index] = not silent
        self._local.degraded_changed()

    def set_device_error(self, index: int, error: bool) -> None:
        """A persistent hardware fault (0x603F = 0x5000) of axis ``index``'s drive from the next step (``error``
        False: the cause has gone; the drive stays in Fault until a fault reset, MC_Reset)."""
        self._check_index(index)
        if error:
            self.device.inject_fault(index, HARDWARE_ERROR_CODE, persistent=True)
        else:
            self.device.clear_fault(index)

    def inject_fault(self, index: int, code: int, persistent: bool = False) -> None:
        """A drive fault with 0x603F ``code`` (:meth:`.device.Cia402Device.inject_fault`)."""
        self.device.inject_fault(index, code, persistent)

    def set_probe_signal(self, index: int, level: bool, offset: float) -> None:
        """Touch probe input 2 of the simulated drive (MC_TouchProbe's input 1): :meth:`.device.Cia402Device.set_probe_signal`
        (NotImplementedError on an axis with a sensor pattern, ValueError for an offset outside the cycle)."""
        self.device.set_probe_signal(index, level, offset)

    def _check_index(self, index: int) -> None:
        if not 0 <= int(index) < len(self.act_pos):
            raise IndexError(f"no axis index {index}")
