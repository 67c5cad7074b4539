"""AXACT: against the wire contract (a scripted NC: the request(s) of every MODE, STOP priority,
BUSY until the reply, TMOUT), then against the real NcCore: the motion of every MODE, the timeout
(0x745), ERR/ERRID reset by the next command."""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import ErrorCodes, make_reply
from nc_server.core import AxisParams
from plc_client import AXACT, AXIS_REF
from znc_testing.plc_rig import ACTIVE, MOVING, Rig, ScriptNc, powered

P = AxisParams()


# ---- against the contract (scripted NC) -------------------------------------------------------------
V, X = 12.0, 34.0
READ = {1008: 400.0, 1001: 20.0, 1040: 0.5}  # AxisRapidTraverseVelocity, AxisVeloManSlow, AxisEncoderScalingFactor
TABLE = [
    (1, (), ("MoveAbsolute", {"Position": X, "Velocity": V})),
    (2, (), ("MoveRelative", {"Distance": X, "Velocity": V})),
    (3, (), ("MoveVelocity", {"Velocity": V, "Direction": 1})),
    (4, (), ("MoveVelocity", {"Velocity": V, "Direction": 3})),
    (5, (), ("MoveModulo", {"Position": X, "Velocity": V, "Direction": 1})),
    (261, (), ("MoveModulo", {"Position": X, "Velocity": V, "Direction": 2})),
    (517, (), ("MoveModulo", {"Position": X, "Velocity": V, "Direction": 1})),
    (773, (), ("MoveModulo", {"Position": X, "Velocity": V, "Direction": 3})),
    (1029, (), ("MoveModulo", {"Position": X, "Velocity": V, "Direction": 4})),
    (272, (), ("Jog", {"Mode": 0, "Direction": 1})),
    (273, (), ("Jog", {"Mode": 0, "Direction": 3})),
    (528, (), ("Jog", {"Mode": 1, "Direction": 1})),
    (529, (), ("Jog", {"Mode": 1, "Direction": 3})),
    (784, (1008,), ("MoveVelocity", {"Velocity": 400.0, "Direction": 1})),
    (785, (1008,), ("MoveVelocity", {"Velocity": 400.0, "Direction": 3})),
    (288, (1040, 1001), ("MoveRelative", {"Distance": 0.5, "Velocity": 20.0})),
    (289, (1040, 1001), ("MoveRelative", {"Distance": -0.5, "Velocity": 20.0})),
    (544, (1001,), ("MoveRelative", {"Distance": 0.001, "Velocity": 20.0})),
    (545, (1001,), ("MoveRelative", {"Distance": -0.001, "Velocity": 20.0})),
    (800, (1001,), ("MoveRelative", {"Distance": 0.01, "Velocity": 20.0})),
    (801, (1001,), ("MoveRelative", {"Distance": -0.01, "Velocity": 20.0})),
    (1056, (1001,), ("MoveRelative", {"Distance": 0.1, "Velocity": 20.0})),
    (1057, (1001,), ("MoveRelative", {"Distance": -0.1, "Velocity": 20.0})),
    (1312, (1001,), ("MoveRelative", {"Distance": 1.0, "Velocity": 20.0})),
    (1313, (1001,), ("MoveRelative", {"Distance": -1.0, "Velocity": 20.0})),
]


def axact_on(nc: ScriptNc, fb: AXACT, st: dict) -> None:
    def call() -> None:
        fb(**st)
        check(fb)
    nc.calls.append(call)


@pytest.mark.parametrize("mode, reads, expect", TABLE)
def test_contract_mode_table(mode: int, reads: tuple[int, ...], expect: tuple[str, dict]) -> None:
    nc = ScriptNc()
    nc.cycle_once()
    fb = AXACT(nc="nc1")
    st = {"AXID": 1, "START": True, "MODE": mode, "VELOCITY": V, "TARGPOS": X}
    axact_on(nc, fb, st)
    nc.cycle_once()
    assert fb.BUSY
    if reads:
        sent = nc.port.sent[-len(reads):]
        assert [(p.cmd, p.args["ParameterNumber"]) for p in sent] == [("ReadParameter", n) for n in reads]
        for p in sent:
            nc.port._deliver(p, make_reply(p.id, p.cmd, 0, cycle=nc.nc_cycle, value=READ[p.args["ParameterNumber"]]))
        nc.cycle_once()
        assert fb.BUSY
    p = nc.port.sent[-1]
    assert (p.cmd, p.args) == expect
    assert p.axis_id == 1 and p.nc == "nc1"
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=5 if p.cmd != "ReadParameter" else None)
    nc.cycle_once()
    assert not fb.BUSY and not fb.ERR


def test_contract_modulo_5_negative_targpos() -> None:
    nc = ScriptNc()
    nc.cycle_once()
    fb = AXACT()
    axact_on(nc, fb, {"AXID": 1, "START": True, "MODE": 5, "VELOCITY": V, "TARGPOS": -450.0})
    nc.cycle_once()
    assert nc.port.sent[-1].args == {"Position": 450.0, "Velocity": V, "Direction": 3}


def test_contract_stop_priority_busy_and_timeout() -> None:
    nc = ScriptNc()
    nc.cycle_once()
    fb = AXACT()
    st = {"AXID": 1, "START": True, "STOP": True, "MODE": 3, "VELOCITY": V, "TMOUT": 0.1}
    axact_on(nc, fb, st)
    nc.cycle_once()
    assert [p.cmd for p in nc.port.sent] == ["Halt"] and nc.port.sent[0].args == {}
    assert fb.BUSY
    st.update(START=False, STOP=False)
    nc.cycle_once()
    st.update(START=True)  # an edge while BUSY: not accepted
    nc.cycle_once()
    assert len(nc.port.sent) == 1 and fb.BUSY
    nc.cycle_once(8)
    assert fb.ERR and fb.ERRID == ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT and not fb.BUSY
    assert nc.port.sent[0].abandoned
    st.update(START=False)
    nc.cycle_once()
    assert fb.ERR, "kept until the next command"
    st.update(START=True)
    nc.cycle_once()
    assert not fb.ERR and fb.BUSY and nc.port.sent[-1].cmd == "MoveVelocity"
    nc.port.answer(nc.port.sent[-1], error=ErrorCodes.NC_VELOCITY_NOT_ALLOWED, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert fb.ERR and fb.ERRID == 0x4221 and not fb.BUSY


def test_contract_read_error_and_bad_value() -> None:
    nc = ScriptNc()
    nc.cycle_once()
    fb = AXACT()
    st = {"AXID": 1, "START": True, "MODE": 784}
    axact_on(nc, fb, st)
    nc.cycle_once()
    p = nc.port.sent[-1]
    nc.port.answer(p, error=ErrorCodes.ADSERR_DEVICE_INVALIDOFFSET, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert fb.ERR and fb.ERRID == 0x703 and len(nc.port.sent) == 1
    st.update(START=False)
    nc.cycle_once()
    st.update(START=True)
    nc.cycle_once()
    p = nc.port.sent[-1]
    nc.port._deliver(p, make_reply(p.id, p.cmd, 0, cycle=nc.nc_cycle, value=True))  # not a number
    nc.cycle_once()
    assert fb.ERR and fb.ERRID == ErrorCodes.MC_PARAMETER_NOT_CORRECT and len(nc.port.sent) == 2


# ---- BUSY and the frames, in the order the network delivers them (issue 17) ---------------------------
def _started(nc: ScriptNc, fb: AXACT, st: dict) -> Any:
    """AXACT called with ``st`` every cycle; the edge's request (already sent)."""
    axact_on(nc, fb, st)
    nc.cycle_once()
    assert fb.BUSY
    return nc.port.sent[-1]


@pytest.mark.parametrize("st", [{"START": True, "MODE": 1, "VELOCITY": V, "TARGPOS": X}, {"STOP": True}],
                         ids=["start", "stop"])
def test_busy_falls_with_the_frame_of_the_reply_cycle(nc: ScriptNc, st: dict) -> None:
    """TcMC AXACT: "as soon as BUSY goes FALSE, the bit 'axis has transport instruction' is set". The reply
    arrives first, the frame of its cycle one PLC cycle later: BUSY falls with that frame (HasJob TRUE)."""
    fb = AXACT()
    p = _started(nc, fb, {"AXID": 1, **st})
    effect = nc.nc_cycle + 10  # the frame after the next one shows it
    nc.port.answer(p, cycle=effect, cmdno=5)
    nc.cycle_once()  # the reply is here, the frame is the one before the command's cycle
    assert fb.axis is not None and not fb.axis.Status.HasJob and fb.axis.Status.NcCycleCounter < effect
    assert fb.BUSY and not fb.ERR, "BUSY falls only with a frame that shows the command"
    nc.state(MOVING)  # the NC's frame of that cycle: the axis has its job
    nc.set_jobs(active=(5, ACTIVE))
    nc.cycle_once()
    assert fb.axis.Status.NcCycleCounter >= effect
    assert not fb.BUSY and not fb.ERR and fb.axis.Status.HasJob


def test_reply_and_frame_together_busy_falls_at_once(nc: ScriptNc) -> None:
    fb = AXACT()
    p = _started(nc, fb, {"AXID": 1, "START": True, "MODE": 3, "VELOCITY": V})
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=5)
    nc.state(MOVING)
    nc.cycle_once()
    assert not fb.BUSY and not fb.ERR and fb.axis is not None and fb.axis.Status.HasJob


def test_tmout_bounds_the_wait_for_the_frame(nc: ScriptNc) -> None:
    """Accepted, but no frame shows it within TMOUT: ERR 0x745; the accepted command is left running."""
    fb = AXACT()
    p = _started(nc, fb, {"AXID": 1, "START": True, "MODE": 3, "VELOCITY": V, "TMOUT": 0.1})
    nc.port.answer(p, cycle=nc.nc_cycle + 10_000, cmdno=5)  # frames of that cycle never come in time
    nc.cycle_once(8)
    assert fb.BUSY and not fb.ERR
    nc.cycle_once(3)
    assert not fb.BUSY and fb.ERR and fb.ERRID == ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT == 0x745
    nc.cycle_once(5)
    assert [q.cmd for q in nc.port.sent] == ["MoveVelocity"], "nothing stops the accepted command"


@pytest.mark.parametrize("answered", [True, False], ids=["accepted", "unanswered"])
def test_nc_restart_before_the_frame_gives_4b0f(nc: ScriptNc, answered: bool) -> None:
    fb = AXACT()
    p = _started(nc, fb, {"AXID": 1, "START": True, "MODE": 1, "VELOCITY": V, "TARGPOS": X, "TMOUT": 5.0})
    if answered:
        nc.port.answer(p, cycle=nc.nc_cycle + 10, cmdno=5)
        nc.cycle_once()
        assert fb.BUSY
    nc.nc_cycle = 1  # a new NC instance: its frames start again
    nc.cycle_once()
    assert not fb.BUSY and fb.ERR and fb.ERRID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE == 0x4B0F
    assert p.abandoned != answered, "an unanswered request is abandoned (a late acceptance gets stopped)"


# ---- against the real NC ------------------------------------------------------------------------------
def check(fb: AXACT) -> None:
    if not fb.ERR:
        assert fb.ERRID == 0
    assert not (fb.BUSY and fb.ERR)


def drive(rig: Rig, calls: dict, fb: AXACT, inputs: dict[str, Any], limit: int = 20) -> int:
    """Run ``fb`` with ``inputs`` until BUSY fell; returns the cycles it took (checks outputs)."""
    st = dict(inputs)

    def body(p: Any) -> None:
        fb(**st)
        check(fb)

    calls["body"] = body
    n = rig.run(limit, until=lambda: not fb.BUSY)
    return n


def edge(rig: Rig, calls: dict, fb: AXACT, **inputs: Any) -> None:
    """START/STOP low for a cycle, then the given inputs (a rising edge where START/STOP is TRUE)."""
    base = {k: v for k, v in inputs.items() if k not in ("START", "STOP")}
    calls["body"] = lambda p: fb(START=False, STOP=False, **base)
    rig.run(1)
    drive(rig, calls, fb, inputs)


def test_mode_1_absolute_busy_until_accepted(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    fb = AXACT()
    calls["body"] = lambda p: fb(AXID=1, START=True, MODE=1, TARGPOS=30.0, VELOCITY=100.0)
    rig.run(1)
    assert fb.BUSY and not ax.Status.HasJob
    rig.run(1)
    assert not fb.BUSY and not fb.ERR, "BUSY falls with the NC's acceptance"
    assert ax.Status.HasJob, "... and then the axis has its job"
    rig.run_until(lambda: not ax.Status.HasJob, 200)
    assert math.isclose(ax.ActPos, 30.0, abs_tol=0.02)
    assert fb.axis is not None and (fb.axis.nc, fb.axis.axis_id) == ("nc1", 1)


def test_modes_2_3_4_relative_and_continuous(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    fb = AXACT()
    edge(rig, calls, fb, AXID=1, START=True, MODE=2, TARGPOS=-5.0, VELOCITY=50.0)
    rig.run_until(lambda: not ax.Status.HasJob, 200)
    assert math.isclose(ax.ActPos, -5.0, abs_tol=0.02)
    edge(rig, calls, fb, AXID=1, START=True, MODE=3, VELOCITY=40.0)
    rig.run(20)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 40.0)
    edge(rig, calls, fb, AXID=1, START=True, MODE=4, VELOCITY=30.0)
    rig.run(20)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), -30.0)
    edge(rig, calls, fb, AXID=1, STOP=True)
    assert not fb.ERR
    rig.run_until(lambda: ax.Status.StandStill, 100)
    assert not ax.Status.MotionCommandsLocked, "STOP is a Halt: the axis is not locked"
    edge(rig, calls, fb, AXID=1, START=True, MODE=2, TARGPOS=1.0, VELOCITY=50.0)
    assert not fb.ERR and ax.Status.HasJob


def modulo_rig() -> Rig:
    return Rig(params=AxisParams(Modulo=True, AxisEncoderModuloValue=360.0))


@pytest.mark.parametrize("mode, targ, end, direction", [
    (5, 450.0, 90.0 + 360.0, 1),     # from 90: positive, one extra turn (TcMC 3.5 example)
    (5, -45.0, 45.0, -1),            # negative TARGPOS: negative direction to |TARGPOS|
    (261, 45.0, 45.0, -1),           # shortest way from 90 to 45
    (517, 45.0, 405.0, 1),           # positive
    (773, 135.0, 135.0 - 360.0, -1), # negative
])
def test_modulo_modes(mode: int, targ: float, end: float, direction: int) -> None:
    rig = modulo_rig()
    ax, _, calls = powered(rig)
    fb = AXACT()
    edge(rig, calls, fb, AXID=1, START=True, MODE=1, TARGPOS=90.0, VELOCITY=500.0)
    rig.run_until(lambda: not ax.Status.HasJob and ax.Status.InTargetPosition, 300)
    seen: list[float] = []
    edge(rig, calls, fb, AXID=1, START=True, MODE=mode, TARGPOS=targ, VELOCITY=500.0)
    assert not fb.ERR, f"0x{fb.ERRID:X}"
    body = calls["body"]
    calls["body"] = lambda p: (body(p), seen.append(float(ax.NcToPlc["SetVelo"])))
    rig.run_until(lambda: not ax.Status.HasJob and ax.Status.InTargetPosition, 500)
    assert math.isclose(ax.ActPos, end, abs_tol=0.05)
    assert (max(seen) if direction > 0 else -min(seen)) > 1.0


def test_mode_1029_current_direction() -> None:
    rig = modulo_rig()
    ax, _, calls = powered(rig)
    fb = AXACT()
    edge(rig, calls, fb, AXID=1, START=True, MODE=4, VELOCITY=30.0)  # moving negative
    rig.run(10)
    edge(rig, calls, fb, AXID=1, START=True, MODE=1029, TARGPOS=300.0, VELOCITY=30.0)
    assert not fb.ERR, f"0x{fb.ERRID:X}"
    rig.run_until(lambda: not ax.Status.HasJob, 1500)
    assert math.isclose(ax.ActPos, -60.0, abs_tol=0.05), "continued in negative direction to 300 (mod 360)"


@pytest.mark.parametrize("mode, velo", [(272, P.AxisVeloManSlow), (273, -P.AxisVeloManSlow),
                                        (528, P.AxisVeloManFast), (529, -P.AxisVeloManFast),
                                        (784, P.AxisRapidTraverseVelocity), (785, -P.AxisRapidTraverseVelocity)])
def test_manual_and_rapid_velocities(rig: Rig, mode: int, velo: float) -> None:
    ax, _, calls = powered(rig)
    fb = AXACT()
    edge(rig, calls, fb, AXID=1, START=True, MODE=mode, VELOCITY=float("nan"), TARGPOS=float("nan"))
    assert not fb.ERR, f"0x{fb.ERRID:X} (VELOCITY/TARGPOS are not used in this mode)"
    rig.run(30)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), velo)
    edge(rig, calls, fb, AXID=1, STOP=True)
    rig.run_until(lambda: ax.Status.StandStill, 200)


@pytest.mark.parametrize("mode, dist", [(288, 0.25), (289, -0.25), (544, 0.001), (545, -0.001), (800, 0.01),
                                        (801, -0.01), (1056, 0.1), (1057, -0.1), (1312, 1.0), (1313, -1.0)])
def test_relative_steps(mode: int, dist: float) -> None:
    rig = Rig(params=AxisParams(AxisEncoderScalingFactor=0.25, AxisTargetPositionWindow=0.0001))
    ax, _, calls = powered(rig)
    fb = AXACT()
    seen: list[float] = []
    edge(rig, calls, fb, AXID=1, START=True, MODE=mode)
    assert not fb.ERR, f"0x{fb.ERRID:X}"
    body = calls["body"]
    calls["body"] = lambda p: (body(p), seen.append(abs(float(ax.NcToPlc["SetVelo"]))))
    rig.run_until(lambda: not ax.Status.HasJob, 100)
    rig.run(5)
    assert math.isclose(ax.ActPos, dist, abs_tol=1e-4)
    assert max(seen) <= P.AxisVeloManSlow + 1e-9


def test_reads_parameters_at_every_start(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    fb = AXACT()
    edge(rig, calls, fb, AXID=1, START=True, MODE=784)
    rig.run(30)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), P.AxisRapidTraverseVelocity)
    rig.plcs["plc1"].port.send("nc1", 1, "WriteParameter", ParameterNumber=1008, Value=123.0)
    edge(rig, calls, fb, AXID=1, START=True, MODE=784)
    rig.run(30)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 123.0)


def test_stop_wins_over_start(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    fb = AXACT()
    edge(rig, calls, fb, AXID=1, START=True, MODE=3, VELOCITY=40.0)
    rig.run(20)
    assert ax.Status.ContinuousMotion and float(ax.NcToPlc["SetVelo"]) > 0
    # START (reverse) and STOP rise in the same cycle: only the stop is sent
    edge(rig, calls, fb, AXID=1, START=True, STOP=True, MODE=4, VELOCITY=40.0)
    assert not fb.ERR, f"0x{fb.ERRID:X}"
    rig.run_until(lambda: ax.Status.StandStill, 100)
    rig.run(10)
    assert ax.Status.StandStill and float(ax.NcToPlc["SetVelo"]) == 0.0


def test_edges_while_busy_are_ignored(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    fb = AXACT()
    plc = rig.plcs["plc1"]
    plc.port.hold = True  # keep BUSY up: the replies are held back
    calls["body"] = lambda p: fb(AXID=1, START=True, STOP=False, MODE=3, VELOCITY=40.0, TMOUT=5.0)
    rig.run(3)
    assert fb.BUSY
    cmd = int(rig.rec()["CmdNo"])
    calls["body"] = lambda p: fb(AXID=1, START=True, STOP=True)  # a STOP edge while BUSY
    rig.run(3)
    assert fb.BUSY and int(rig.rec()["CmdNo"]) == cmd, "not accepted: nothing sent"
    plc.port.hold = False
    plc.port.release_held()
    rig.run(2)
    assert not fb.BUSY and not fb.ERR
    rig.run(20)
    assert ax.Status.ContinuousMotion, "the STOP edge during BUSY was not remembered"
    edge(rig, calls, fb, AXID=1, STOP=True)
    rig.run_until(lambda: ax.Status.StandStill, 100)


def test_invalid_mode_and_reset_by_the_next_command(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    fb = AXACT()
    before = int(rig.rec()["CmdNo"])
    edge(rig, calls, fb, AXID=1, START=True, MODE=6, TARGPOS=1.0, VELOCITY=1.0)
    assert fb.ERR and fb.ERRID == ErrorCodes.MC_INVALID_MODE and not fb.BUSY
    rig.run(3)
    assert fb.ERR, "ERR is kept until the next command"
    assert int(rig.rec()["CmdNo"]) == before
    edge(rig, calls, fb, AXID=1, START=True, MODE=1, TARGPOS=1.0, VELOCITY=1e9)
    assert fb.ERR and fb.ERRID == ErrorCodes.NC_VELOCITY_NOT_ALLOWED, "the NC's code"
    edge(rig, calls, fb, AXID=1, START=True, MODE=1, TARGPOS=float("inf"), VELOCITY=10.0)
    assert fb.ERR and fb.ERRID == ErrorCodes.MC_PARAMETER_NOT_CORRECT
    edge(rig, calls, fb, AXID=0, START=True, MODE=1, TARGPOS=1.0, VELOCITY=10.0)
    assert fb.ERR and fb.ERRID == ErrorCodes.NC_AXIS_ID_NOT_ALLOWED
    edge(rig, calls, fb, AXID=7, START=True, MODE=1, TARGPOS=1.0, VELOCITY=10.0)
    assert fb.ERR and fb.ERRID == ErrorCodes.NC_AXIS_ID_NOT_ALLOWED, "the NC has no axis 7"
    edge(rig, calls, fb, AXID=1, START=True, MODE=1, TARGPOS=2.0, VELOCITY=10.0, TMOUT=0)
    assert fb.ERR and fb.ERRID == ErrorCodes.MC_PARAMETER_NOT_CORRECT
    edge(rig, calls, fb, AXID=1, STOP=True, TMOUT=1.0)
    assert not fb.ERR and fb.ERRID == 0


def test_timeout_gives_745(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    fb = AXACT()
    plc = rig.plcs["plc1"]
    plc.port.hold = True  # the NC executes, its replies never arrive
    st = {"start": True}
    calls["body"] = lambda p: fb(AXID=1, START=st["start"], MODE=3, VELOCITY=10.0, TMOUT=0.2)
    n = rig.run_until(lambda: not fb.BUSY, 100)
    assert fb.ERR and fb.ERRID == ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT == 0x745
    assert 19 <= n <= 22, f"TMOUT 0.2 s = 20 PLC cycles, took {n}"
    plc.port.hold = False
    plc.port.release_held()
    rig.run(5)  # the late acceptance: the task halts the axis it did not expect to move
    rig.run_until(lambda: ax.Status.StandStill, 200)
    assert fb.ERR, "kept until the next command"


def test_needs_a_running_task_and_no_axis() -> None:
    fb = AXACT()
    fb(AXID=1, START=True, MODE=1, TARGPOS=1.0, VELOCITY=1.0)
    assert fb.ERR and fb.ERRID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE
    with pytest.raises(TypeError):
        fb(Axis=AXIS_REF(), START=False)
    with pytest.raises(ValueError):
        AXACT(nc="")
