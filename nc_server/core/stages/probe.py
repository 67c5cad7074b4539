"""The touch probe stage: the drive's position latch, evaluated after the drive (TcMC 4.21, 4.22).

MC_TouchProbe arms the latch of touch probe input 1 (``DriveABC.latch_probe``) for a rising or a
falling edge; each cycle the armed axes ask their drive whether such an edge happened during the
cycle just stepped, and where (the drive interpolates the actual position within the cycle, and
says when: RecordedTimeNs is the NC time of the event, not of the cycle). With WindowOnly a
position outside the window is rejected and the latch stays armed (TcMC: "automatically newly
activated"). A recorded position ends the probe cycle DONE: TouchProbeCounter counts it,
RecordedPosition/RecordedTimeNs keep it, StateDWord.ExternalLatchValid is set until the next
MC_TouchProbe or MC_AbortTrigger. MC_Reset while armed ends it ERROR 0x4B0C (latch disabled).
Each MC_TouchProbe tells the drive (``DriveABC.arm_probe``): a drive whose latch keeps a session across
cycles starts a new one, so a latch of the arming before (still in flight) never completes the new command.

NCTOPLC.TouchProbeState (TcMC does not publish its bits; this NC's choice): bit 0 the latch of
input 1 is armed, bit 1 a recorded position is valid. StateDWord3 bit 0 (TouchProbe1InputState)
shows the input's level.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from nc_schema import CmdState, ErrorCodes, NcError, next_cmdno

from ..commands import core_command
from ..probe import check_trigger_input, in_window, modulo_position

if TYPE_CHECKING:
    from ..context import CoreContext

ARMED, VALID = 1, 2  # TouchProbeState bits


class ProbeStage:
    """Per axis: the armed latch (edge, window) and the last recorded event."""

    name = "probe"

    def __init__(self, n: int) -> None:
        self.armed = np.zeros(n, dtype=bool)
        self.falling = np.zeros(n, dtype=bool)
        self.window: list[tuple[float, float, bool] | None] = [None] * n  # (first, last, modulo)
        self.modulo = np.zeros(n, dtype=bool)  # RecordedPosition as a modulo position
        self.cmd_no = np.zeros(n, dtype=np.uint16)
        self.state = np.zeros(n, dtype=np.uint16)
        self.error = np.zeros(n, dtype=np.uint32)
        self.counter = np.zeros(n, dtype=np.uint32)
        self.recorded = np.zeros(n)
        self.recorded_ns = np.zeros(n, dtype=np.uint64)
        self.valid = np.zeros(n, dtype=bool)
        self.rows = np.zeros(0, dtype=np.intp)
        self.changed: list[int] = []

    @property
    def active(self) -> bool:
        return bool(self.rows.size)

    def touch_state(self) -> np.ndarray:
        """NCTOPLC.TouchProbeState of every axis."""
        return self.armed * np.uint32(ARMED) | self.valid * np.uint32(VALID)

    def _end(self, i: int, state: CmdState, error: int = 0) -> None:
        if self.armed[i]:
            self.armed[i] = False
            self.state[i], self.error[i] = int(state), error
            self.rows = self.armed.nonzero()[0]
        self.changed.append(i)

    def disarm_on_reset(self, i: int) -> None:
        """MC_Reset: an armed latch is disabled (0x4B0C)."""
        if self.armed[i]:
            self._end(i, CmdState.ERROR, int(ErrorCodes.MC_LATCH_DISABLED))

    def run(self, core: CoreContext) -> None:
        """After the drive step: latch events of the armed axes (NC positions)."""
        rows = self.rows
        a = core.axes
        prev = core.prev_act_pos[rows] - a.offset[rows]  # (drive positions)
        found, pos, frac = core.drive.latch_probe(rows, self.falling[rows], prev)
        if not np.count_nonzero(found):
            return
        dt_ns = core.cycle_time * 1e9
        for k in np.flatnonzero(found).tolist():
            i = int(rows[k])
            p = float(pos[k] + a.offset[i])
            period = float(core.params[i].AxisEncoderModuloValue)
            w = self.window[i]
            if w is not None and not in_window(p, w[0], w[1], w[2], period):
                continue  # outside the window: rejected, the latch stays armed
            self.recorded[i] = modulo_position(p, period) if self.modulo[i] else p
            # the stepped cycle runs from the previous cycle's time to this one's
            self.recorded_ns[i] = max(int(core.nc_time_ns - dt_ns + float(frac[k]) * dt_ns), 0)
            self.counter[i] += 1
            self.valid[i] = True
            self._end(i, CmdState.DONE)
        core.state_dirty = True


@core_command("TouchProbe")
def cmd_touch_probe(core: CoreContext, i: int, req: Mapping[str, Any]) -> dict[str, Any]:
    """TouchProbe: arm the latch (a running probe cycle of the axis ends ABORTED: replaced).

    Raises:
        NcError: 0x4B0B trigger input not supported / not correct; 0x4B06 a non-finite window or an
            absolute one with FirstPosition > LastPosition (empty: only modulo windows wrap).
    """
    check_trigger_input(int(req.get("EncoderID", 1)), int(req.get("TouchProbe", 1)), int(req.get("Edge", 0)))
    st: ProbeStage = core.probe
    window = None
    if req.get("WindowOnly"):
        first, last = float(req.get("FirstPosition", 0.0)), float(req.get("LastPosition", 0.0))
        if not (np.isfinite(first) and np.isfinite(last)):
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, "FirstPosition/LastPosition must be finite")
        window = (first, last, bool(req.get("ModuloPositions")))
        if not window[2] and first > last:  # (only modulo windows wrap: an absolute one would be empty)
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT,
                          f"absolute window FirstPosition {first} > LastPosition {last} is empty")
    if st.armed[i]:
        st._end(i, CmdState.ABORTED)
    # a new arming, also with the same edge: the drive must not report a latch of the arming before
    core.drive.arm_probe(np.array([i], dtype=np.intp))
    q = core.queues[i]
    cmd_no = q.newest = next_cmdno(q.newest)
    st.armed[i] = True
    st.falling[i] = int(req.get("Edge", 0)) == 1
    st.window[i] = window
    st.modulo[i] = bool(req.get("ModuloPositions"))
    st.cmd_no[i], st.state[i], st.error[i] = cmd_no, int(CmdState.ACTIVE), 0
    st.valid[i] = False
    st.rows = st.armed.nonzero()[0]
    st.changed.append(i)
    core.state_dirty = True
    return {"cmd_no": cmd_no}


@core_command("AbortTrigger")
def cmd_abort_trigger(core: CoreContext, i: int, req: Mapping[str, Any]) -> dict[str, Any]:
    """AbortTrigger: disarm; a running probe cycle ends ABORTED."""
    st: ProbeStage = core.probe
    st.valid[i] = False
    st._end(i, CmdState.ABORTED)
    core.state_dirty = True
    return {}


@core_command("SimProbeSignal")
def cmd_sim_probe_signal(core: CoreContext, i: int, req: Mapping[str, Any]) -> dict[str, Any]:
    """SimProbeSignal: a simulated edge of input 1 inside the next cycle (simulated drive only).

    Raises:
        NcError: 0x4251 the drive has no simulated input; 0x4B06 Offset outside [0, cycle time).
    """
    try:
        core.drive.set_probe_signal(i, bool(req["Level"]), float(req.get("Offset", 0.0)))
    except NotImplementedError as exc:
        raise NcError(ErrorCodes.NC_FUNCTION_NOT_SUPPORTED, str(exc) or "the drive has no simulated probe input") from None
    except ValueError as exc:
        raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, str(exc)) from None
    return {}
