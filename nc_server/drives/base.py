"""The drive (hardware) interface of the NC: what a real drive must implement.

A drive serves all axes of one NC at once, column-wise (numpy arrays indexed like
``NcCore.axis_ids``), so a cycle costs a few vector operations however many axes
there are. Positions in axis units, velocities in units/s, accelerations in units/s^2.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.params import AxisParams


@dataclass(frozen=True)
class DriveContext:
    """What a backend may need beyond its axes' parameters, given by the NC server when it builds the drives.

    Attributes:
        nc_name: the NC's name (``[nc] name``; key prefix ``nc/<name>``).
        options: the backend's own section ``[drives.<backend>]`` of the NC's TOML (bus, channel, ...).
        zenoh: the NC's session settings (``nc_server.server.config.ZenohSettings``; None in a pure core
            test), for backends that reach their drives over zenoh.
        axis_ids: the AxisIds of the backend's axes, in order (None: not known, e.g. a test building a backend
            alone); a remote drive host checks them against the axes it serves.
    """

    nc_name: str = "nc1"
    options: Mapping[str, Any] = field(default_factory=dict)
    zenoh: Any = None
    axis_ids: tuple[int, ...] | None = None


class DriveABC(ABC):
    """A set of drives, one per axis.

    Attributes:
        act_pos: actual positions [u], updated by :meth:`step`.
        act_velo: actual velocities [u/s].
        act_acc: actual accelerations [u/s^2].
        ready: drive ready to be enabled (False: the NC refuses starts with 0x4225).
        io_valid: the drive's I/O data are valid (False: e.g. EtherCAT WcState; the NC shows
            StateDWord.IoDataInvalid, ErrorPropagationDelayed for 3 cycles, then axis error 0x4655).
        device_error: the drive hardware reports an error (StateDWord.DriveDeviceError; axis error
            0x4650 on an enabled axis; such a drive is not ``ready``).
        faulty: any axis has invalid I/O data, a device error, lost communication or does not follow (a
            plain bool: the NC's drive monitor does nothing while it is False).
        following: the drive follows the NC's set-points (CiA 402: Operation enabled). On an enabled axis
            whose drive does not follow (it stopped itself after a fault, or is still being switched on), the NC
            runs no ramp: its set-point follows the actual position.
        comm_error: the drive's communication is lost (heartbeat, lease): axis error 0x4651.
        error_code: the drive's own error code (CiA 402 0x603F; 0: none), shown in the stats and nc-status.
        input_age: the age of the inputs used in the last step [NC cycles] (0: fresh; a fieldbus or a remote
            drive delivers them a cycle or more late), shown in the stats (``drive_input_age``).
        simulated: True for simulated drives (OpModeDWord.OpModeSimulationAxis).
    """

    simulated: bool = False

    def __init__(self, params: Sequence[AxisParams], cycle_time: float) -> None:
        n = len(params)
        self.cycle_time = float(cycle_time)
        self.act_pos = np.zeros(n)
        self.act_velo = np.zeros(n)
        self.act_acc = np.zeros(n)
        self.ready = np.ones(n, dtype=bool)
        self.io_valid = np.ones(n, dtype=bool)
        self.device_error = np.zeros(n, dtype=bool)
        self.following = np.ones(n, dtype=bool)
        self.comm_error = np.zeros(n, dtype=bool)
        self.error_code = np.zeros(n, dtype=np.uint16)
        self.input_age = np.zeros(n, dtype=np.int64)
        self.faulty = False

    @classmethod
    def from_config(cls, params: Sequence[AxisParams], cycle_time: float,
                    axis_options: Sequence[Mapping[str, Any]], context: DriveContext) -> DriveABC:
        """The drives of ``params`` as the NC's TOML configures them.

        Args:
            params: the axes this backend serves, in order.
            cycle_time: the NC cycle [s].
            axis_options: per axis, its ``Drive`` table without ``backend`` (e.g. ``{"node_id": 2}``).
            context: the backend's ``[drives.<name>]`` options and the NC's name and session settings.

        Raises:
            ConfigError: an option the backend does not know or a bad value (a start error of the NC).
            Exception: the hardware cannot be opened (a missing bus or node: a clear start error, not a hang).

        Default: a backend without options (``cls(params, cycle_time)``); any option is a ConfigError.
        """
        from ..core.params import ConfigError
        for i, opts in enumerate(axis_options):
            if opts:
                raise ConfigError(f"axis[{i}].Drive", f"the {cls.__name__} backend takes no options, got "
                                                      f"{', '.join(sorted(opts))}")
        if context.options:
            raise ConfigError("drives", f"the {cls.__name__} backend takes no options, got "
                                        f"{', '.join(sorted(context.options))}")
        return cls(params, cycle_time)

    @property
    def simulated_axes(self) -> np.ndarray:
        """Per axis: its drive is simulated (OpModeDWord.OpModeSimulationAxis); default: ``simulated`` for all."""
        return np.full(len(self.act_pos), bool(self.simulated))

    def reset(self, rows: np.ndarray) -> None:
        """MC_Reset of these axes (int array): acknowledge their drive faults (CiA 402: a rising edge of the
        controlword's fault reset bit). Default: nothing to acknowledge."""

    def resync(self, latched: np.ndarray | None = None) -> None:
        """Another NC drove these drives until now (a hot standby takes over, docs/standby.md): take their current
        state from the newest inputs the link has, sending nothing, so that the first :meth:`step` continues from it
        (its controlword from the drive's power state, its target from where the drive is, not from this object's
        state of when it last exchanged). Called once, just before the first step of the new active NC.

        Args:
            latched: per axis, the NC showed a drive error there until now (the lost NC's 0x4650, replicated): a
                drive out of Operation enabled there is not enabled again before MC_Reset. None: none.

        Default: nothing (a drive in this process that no other NC drives)."""

    @abstractmethod
    def configure(self, index: int, params: AxisParams) -> None:
        """Apply (changed) parameters of one axis.

        An encoder parameter may change the position the drive reports without any motion (``act_pos[index]``
        jumps; the NC notices by comparing it and tells its position jump hooks). The NC changes encoder
        parameters only while the axis's controller is disabled."""

    @abstractmethod
    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        """Advance one NC cycle: command the set-points, read back the actual values.

        Args:
            enabled: controller enable per axis (False: drive disabled, holds).
            set_pos, set_velo, set_acc: set-points of this cycle.
        """

    # -- torque (NCTOPLC SetTorque, ActTorque, their derivatives, TorqueOffset) ------------------------------

    def set_torque_offset(self, values: np.ndarray) -> None:
        """The additive torque per axis [% of rated torque], PLCTONC.ExtTorque as the PLC sent it (the NC
        calls this when a PLCTONC changed; non-finite values are the drive's to judge). Default: ignored."""

    def torque_fields(self) -> np.ndarray | None:
        """The torque fields of every axis: a (6, n) array, rows SetTorque, ActTorque [%], ActTorqueDerivative,
        SetTorqueDerivative [%/s], AbsPhasingPos (0), TorqueOffset [%] (NCTOPLC order); None: nothing changed
        since the last call that gave all zeros (default: a drive that reports no torque, always None). Read-only
        to callers: a drive may hand out the same array in steady cycles without writing it again."""
        return None

    def link_figures(self) -> dict[int, dict[str, Any]]:
        """Per axis (index) the figures of the link to its drive, for the stats (``drive_link``) and nc-status: a
        fieldbus's or a remote host's health (CANopen: NMT state, heartbeat age, missed TPDOs, transmit errors;
        remote: round trip, input age). Called from the stats thread while the cycle runs: it only reads.
        Default: no link (an in-process simulation), ``{}``."""
        return {}

    def latch_sync_pulse(self, rows: np.ndarray, prev_pos: np.ndarray) -> np.ndarray:
        """The encoder's sync (zero) pulse latch, for homing.

        Args:
            rows: axes whose latch is armed.
            prev_pos: their actual positions of the previous cycle [u].

        Returns:
            per row the exact position [u] of a sync pulse passed between ``prev_pos`` and the
            current actual position, NaN where none was passed (default: no latch, all NaN).
        """
        return np.full(len(rows), np.nan)

    # -- touch probe (MC_TouchProbe, TcMC 4.21): input 1 of the drive's probe latch ----------------------------
    # Real drives override these three with their latch hardware; the defaults describe a drive without one.

    def probe_input(self) -> np.ndarray:
        """The current level of touch probe input 1 per axis (StateDWord3.TouchProbe1InputState).

        Returns:
            bool array, one entry per axis: the level at the end of the last stepped cycle
            (default: no probe input, all False).
        """
        return np.zeros(len(self.act_pos), dtype=bool)

    def arm_probe(self, rows: np.ndarray) -> None:
        """A new arming of the touch probe latch (MC_TouchProbe executed) on these axes, before the next
        :meth:`step`: a latch of an earlier arming must not be reported for it (also with the same edge, e.g. a
        re-executed MC_TouchProbe, or MC_AbortTrigger and MC_TouchProbe in one cycle). A drive whose latch
        hardware keeps a session across cycles (CiA 402's probe 2) closes it and opens a new one.

        Args:
            rows: axis indices (int array).

        Default: nothing to do (a drive that only looks at the cycle just stepped, as SimDrive).
        """

    def latch_probe(self, rows: np.ndarray, falling: np.ndarray,
                    prev_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The touch probe latch: the first edge of input 1 during the cycle just stepped.

        Called once per NC cycle after :meth:`step`, only for the axes whose latch is armed.

        Args:
            rows: axis indices whose latch is armed (int array of length m).
            falling: per row, the edge to latch: True = falling edge, False = rising edge.
            prev_pos: their actual drive positions before the :meth:`step` [u] (the drive's frame,
                not the NC's: without the NC's position offset).

        Returns:
            (found, position, fraction), arrays of length m: ``found`` (bool) whether an edge of the
            requested kind happened in the cycle (only the first such edge counts); ``position`` the
            drive position at that event [u], interpolated within the cycle, NaN where none was found;
            ``fraction`` in [0, 1] when within the cycle it happened (0 = at the start, where the axis
            was at ``prev_pos``; 1 = at the end, at the current actual position), NaN where none.
            Default: no latch hardware, nothing is ever found.
        """
        m = len(rows)
        return np.zeros(m, dtype=bool), np.full(m, np.nan), np.full(m, np.nan)

    def set_probe_signal(self, index: int, level: bool, offset: float) -> None:
        """A simulated trigger event: input 1 of one axis takes ``level`` ``offset`` s into the next stepped cycle.

        The level persists until changed; setting the level the input already has is no edge.

        Args:
            index: axis index.
            level: the new input level.
            offset: when within the next stepped cycle [s], 0 <= offset < cycle_time.

        Raises:
            NotImplementedError: the drive has no simulated probe input (default; the NC answers 0x4251).
            ValueError: offset outside 0 <= offset < cycle_time (drives that implement it).
        """
        raise NotImplementedError(f"{type(self).__name__} has no simulated probe input")

    # -- stepper terminal (MC_PowerStepper, TcMC 4.23): simulated drives only -------------------------------------

    def terminal_status(self) -> np.ndarray | None:
        """The status of each axis's stepper terminal (KL2531/KL2541) as NCJOBS_AXIS_REF.DriveStatus shows it:
        bits 0-7 the status byte, 8-23 the status word, 31 set where there is one (schema/params.json
        ``stepper_terminal``); None: no axis has one (default)."""
        return None

    def set_stall(self, index: int, stall: bool) -> None:
        """A simulated stepper stalls (or stops stalling) now.

        Raises:
            NotImplementedError: not a simulated stepper (default; the NC answers 0x4251).
        """
        raise NotImplementedError(f"{type(self).__name__} cannot stall on demand")

    def set_terminal_error(self, index: int, status_word: int) -> None:
        """The error bits of a simulated stepper terminal's status word.

        Raises:
            NotImplementedError: not a simulated stepper (default; the NC answers 0x4251).
        """
        raise NotImplementedError(f"{type(self).__name__} has no simulated stepper terminal")

    def close(self) -> None:
        """Release the hardware (no-op for simulations)."""
