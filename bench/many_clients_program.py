"""The ``plc-run`` program of bench/many_clients.py: every axis of ``$MANY_AXES`` moves back and forth.

Per axis: MC_Power (enables on) and one MC_MoveAbsolute that alternates between ``$MANY_TARGETS``
(default 0 and 40 units at 100 units/s, ~0.45 s per move): a new move on the cycle after the
previous one is Done, so the axis is almost always moving. The program counts what it sent and how
each move ended, and writes its report (JSON) to ``$MANY_REPORT`` about once a second; when the file
``$MANY_STOP`` exists it sends no new move, and once every move has ended it writes a final report
with ``"final": true`` (then it idles until plc-run is stopped).

Counted per axis: ``started`` (rising edges of Execute), ``sent`` (moves whose request went to the NC), ``accepted`` / ``refused`` (their
replies: error 0 / an error or none), ``done``,
``aborted``, ``errors`` (ErrorID -> count, MC_Power's own under ``power:<id>`` (not the axis error its ErrorID also
shows), axis errors under ``axis:<id>``: the
program resets them with MC_Reset, at most once a second, counted in ``resets``; one not ended after
RESET_TIMEOUT_S under ``axis:reset-timeout``), ``reset_numbered`` (the resets the NC answered with a
CmdNo: the axis was still in its error stop ramp, which goes on as a numbered stop job, the reset's own:
nc_server/core/nc.py ``_cmd_reset``), the job records'
``NewestCmdNo`` when the first move was sent and now (the NC's count of the numbers it handed out:
``accepted`` + ``task_accepted`` + ``reset_numbered`` must equal the difference, ``sent`` = ``accepted`` +
``refused``), ``task_sent`` / ``task_accepted`` (motion commands the PLC task sent on its own, not this program: the
Halt that stops a move whose block gave up when the NC's data was lost or that was accepted after its
block timed out, plc_client/task.py "orphans"; the NC numbers them too), ``unexplained`` (the numbers from
``cmdno0`` + 1 to ``cmdno`` that no accepted reply of ours carried, at most 20) and ``doubled`` (numbers
two accepted replies carried), and frame reception: ``invalid`` (cycles with stale data
after the first valid one), ``max_unchanged`` (most consecutive PLC cycles without a newer NC
frame).

A move's request stays counted until its answer comes, also when its block gave up waiting (0x745) and
the next move went out meanwhile: the late answer is counted then (``pending`` while any is open; the
final report waits for them).

``MANY_HOLD=1`` (bench/subscribers.py): no moves at all; the axes are only powered (the client claims
them and sends its PLCTONC every cycle, and takes the NC's frames); reports go on every second with
``powered`` per axis, never final.
"""
from __future__ import annotations

import json
import os
import time
from typing import Any

from nc_schema import MOTION_COMMANDS
from plc_client import AXIS_REF, MC_MoveAbsolute, MC_Power, MC_Reset

NC = os.environ.get("MANY_NC", "nc1")
AXES = [int(a) for a in os.environ["MANY_AXES"].split(",")]
#: an MC_Reset not Done nor Error after this long [s] is given up (counted under ``axis:reset-timeout``)
RESET_TIMEOUT_S = 5.0
REPORT = os.environ["MANY_REPORT"]
STOP = os.environ["MANY_STOP"]
TARGETS = [float(x) for x in os.environ.get("MANY_TARGETS", "0,40").split(",")]
VELOCITY = float(os.environ.get("MANY_VELOCITY", "100"))
HOLD = os.environ.get("MANY_HOLD", "") == "1"
REPORT_PERIOD = 1.0


class _Axis:
    def __init__(self, axis_id: int) -> None:
        self.ax = AXIS_REF(nc=NC, axis_id=axis_id)
        self.power = MC_Power()
        self.move = MC_MoveAbsolute()
        self.reset = MC_Reset()
        self.resetting = False
        self.resets = 0
        self.reset_reqs: list = []  # PendingCommands of our resets not answered yet
        self.reset_numbered = 0
        self.cmdnos: list[int] = []  # the CmdNo of every accepted reply (ours and the task's own commands)
        self.next_reset = 0.0
        self.reset_deadline = 0.0
        self.k = 0
        self.execute = False
        self.busy = False
        self.sent = self.done = self.aborted = self.accepted = self.refused = 0
        self.reqs: list = []  # PendingCommands of our moves not answered yet (a late answer counts too)
        self.errors: dict[str, int] = {}
        self.cmdno0: int | None = None
        self.invalid = 0
        self.seen_valid = False
        self.unchanged = 0
        self.max_unchanged = 0
        self.last_nc_cycle = -1
        self._power_err = False
        self.task_cmds: list = []  # PendingCommands of motion commands the task sent on its own (Halt)

    def cycle(self, stopping: bool) -> None:
        ax = self.ax
        if self.reqs:
            open_ = []
            for req in self.reqs:  # the NC's answers to our moves (also a late one)
                if not req.done:
                    open_.append(req)
                elif req.reply is not None and int(req.reply.get("error", 0)) == 0:
                    self.accepted += 1
                    self.cmdnos.append(int(req.reply.get("CmdNo", 0)))
                else:
                    self.refused += 1
            self.reqs = open_
        if self.reset_reqs:
            open_ = []
            for req in self.reset_reqs:  # a reset during the error stop ramp: the stop job's CmdNo
                if not req.done:
                    open_.append(req)
                elif req.reply is not None and int(req.reply.get("error", 0)) == 0 and int(req.reply.get("CmdNo", 0)):
                    self.reset_numbered += 1
                    self.cmdnos.append(int(req.reply["CmdNo"]))
            self.reset_reqs = open_
        p = self.power(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True)
        st = ax.Status
        if st.Valid:
            self.seen_valid = True
            if st.NcCycleCounter == self.last_nc_cycle:
                self.unchanged += 1
                self.max_unchanged = max(self.max_unchanged, self.unchanged)
            else:
                self.unchanged = 0
                self.last_nc_cycle = st.NcCycleCounter
        elif self.seen_valid:
            self.invalid += 1
        # an axis error (ErrorStop: MC_Power stays Active without Status, its Error/ErrorID show the axis's error,
        # the NC needs MC_Reset; e.g. 0x4655 after a hot-standby takeover on a starved machine): counted under
        # axis:<code> (once per reset, not again under power:), reset as a PLC program does
        if self.resetting:
            r = self.reset(Axis=ax, Execute=True)
            timed_out = not (r.Done or r.Error) and time.monotonic() >= self.reset_deadline
            if timed_out:  # (an MC_Reset that never ends: Execute off, tried again a second later at the earliest)
                self.errors["axis:reset-timeout"] = self.errors.get("axis:reset-timeout", 0) + 1
            if r.Done or r.Error or timed_out:
                self.reset(Axis=ax, Execute=False)
                self.resetting = False
        elif p.Active and st.Valid and st.Error and not stopping and time.monotonic() >= self.next_reset:
            self.next_reset = time.monotonic() + 1.0  # (a cause that persists: one MC_Reset a second)
            key = f"axis:0x{int(st.ErrorId):04X}"
            self.errors[key] = self.errors.get(key, 0) + 1
            self.resets += 1
            self.resetting = True
            self.reset_deadline = time.monotonic() + RESET_TIMEOUT_S
            self.reset(Axis=ax, Execute=True)
            if (req := _request(self.reset)) is not None:
                self.reset_reqs.append(req)
        # MC_Power's own errors (claim refused, 0x4B0F, ...; they take precedence over the axis's): an ErrorID that
        # is the axis's error of this cycle is the axis error counted above, not MC_Power's
        own = bool(p.Error) and not (st.Valid and st.Error and int(p.ErrorID) == int(st.ErrorId))
        if own and not self._power_err:
            key = f"power:0x{int(p.ErrorID):04X}"
            self.errors[key] = self.errors.get(key, 0) + 1
        self._power_err = own
        if not self.execute:
            if self.busy:
                self.move(Axis=ax, Execute=False)  # one cycle with Execute FALSE between two moves
                self.busy = False
                return
            if stopping or not p.Status:
                self.move(Axis=ax, Execute=False)
                return
            if self.cmdno0 is None:
                self.cmdno0 = int(ax.NcJobs["NewestCmdNo"])
            self.execute = True
            self.k += 1
            m = self.move(Axis=ax, Execute=True, Position=TARGETS[self.k % len(TARGETS)], Velocity=VELOCITY)
            if (req := _request(m)) is not None:  # the request went out (else the block refused at once, e.g. 0x4B0F)
                self.sent += 1
                self.reqs.append(req)
        else:
            m = self.move(Axis=ax, Execute=True)
        if m.Done or m.Error or m.CommandAborted:
            if m.Done:
                self.done += 1
            elif m.CommandAborted:
                self.aborted += 1
            else:
                key = f"0x{int(m.ErrorID):04X}"
                self.errors[key] = self.errors.get(key, 0) + 1
            self.execute = False
            self.busy = True

    def task_pending(self) -> bool:
        return any(not p.done for p in self.task_cmds)

    def report(self) -> dict:
        cmdno = int(self.ax.NcJobs["NewestCmdNo"]) if self.ax.Status.Valid else None
        task_nos = [int(p.reply.get("CmdNo", 0)) for p in self.task_cmds
                    if p.reply is not None and int(p.reply.get("error", 0)) == 0 and int(p.reply.get("CmdNo", 0))]
        unexplained, doubled = _unexplained(self.cmdno0, cmdno, self.cmdnos + task_nos)
        return {"task_sent": len(self.task_cmds), "task_accepted": len(task_nos), "task_pending": self.task_pending(),
                "started": self.k, "sent": self.sent, "accepted": self.accepted, "refused": self.refused,
                "reset_numbered": self.reset_numbered, "unexplained": unexplained, "doubled": doubled,
                "pending": len(self.reqs), "powered": bool(self.power.Status),
                "done": self.done, "aborted": self.aborted, "errors": self.errors,
                "cmdno0": self.cmdno0, "cmdno": cmdno, "invalid": self.invalid,
                "max_unchanged": self.max_unchanged, "idle": not self.execute,
                # (why MC_Power has no Status: the claim as the task has it, MC_Power Active, the axis's error)
                "power_active": bool(self.power.Active), "valid": bool(self.ax.Status.Valid),
                "axis_error": f"0x{int(self.ax.NcToPlc.ErrorCode):04X}" if self.ax.Status.Valid else None,
                "claim": repr(self.ax._task.claim_state(self.ax)) if self.ax._task is not None else None,
                "nc_epoch": int(self.ax.nc_epoch), "resets": self.resets}


def _request(block: Any) -> Any:
    """The block's NC request (ExecuteBlock.request; a tree before it, compared by bench/plc_cpu.py --tree,
    keeps it in the private ``_pending``)."""
    return block.request if hasattr(type(block), "request") else block._pending


def _unexplained(first: int | None, last: int | None, seen: list[int]) -> tuple[list[int], list[int]]:
    """The CmdNo values after ``first`` up to ``last`` (NewestCmdNo: 1..65535, wrapping to 1) that ``seen``
    (the accepted replies' numbers) lacks, and those it holds twice; at most 20 each. ``seen`` numbers
    outside the range (a reply newer than ``last``'s frame) are not counted."""
    if first is None or last is None:
        return [], []
    span = (last - first) % 65535
    want = {(first + k - 1) % 65535 + 1 for k in range(1, span + 1)}
    counts: dict[int, int] = {}
    for n in seen:
        if n in want:
            counts[n] = counts.get(n, 0) + 1
    missing = sorted((n for n in want if n not in counts), key=lambda n: (n - first) % 65535)
    twice = sorted(n for n, c in counts.items() if c > 1)
    return missing[:20], twice[:20]


class Program:
    def __init__(self) -> None:
        self.axes = [_Axis(a) for a in AXES]
        self.next_report = 0.0
        self.final = False
        self.t0 = time.monotonic()
        self._hooked = False

    def _hook(self, plc) -> None:  # type: ignore[no-untyped-def]
        """Count the motion commands the task sends on its own (PlcTask.send outside our move
        block's call: the orphan Halt), which the NC numbers like ours."""
        by_id = {a.ax.axis_id: a for a in self.axes}
        send = plc.send

        def counting_send(ax, cmd, **args):  # type: ignore[no-untyped-def]
            p = send(ax, cmd, **args)
            a = by_id.get(ax.axis_id)
            if a is not None and cmd in MOTION_COMMANDS and cmd != "MoveAbsolute":
                a.task_cmds.append(p)
            return p

        plc.send = counting_send
        self._hooked = True

    def cycle(self, plc) -> None:  # type: ignore[no-untyped-def]
        if not self._hooked:
            self._hook(plc)
        stopping = HOLD or (os.path.exists(STOP) if plc.cycle % 10 == 0 or self.final else self._stopping)
        self._stopping = stopping
        for a in self.axes:
            a.cycle(stopping)
        if HOLD and not self._all_powered and all(a.power.Status for a in self.axes):
            self._all_powered = True
            self.next_report = 0.0  # report it now (bench/subscribers.py waits for it)
        now = time.monotonic()
        done = not HOLD and stopping and all(not a.execute and not a.reqs and not a.reset_reqs and not a.task_pending()
                                                 for a in self.axes)
        if (now >= self.next_report and not self.final) or (done and not self.final):
            self.next_report = now + REPORT_PERIOD
            self.final = done
            rep = {"final": done, "cycle": plc.cycle, "overruns": getattr(plc, "overruns", 0),
                   "axes": {str(a.ax.axis_id): a.report() for a in self.axes}}
            tmp = REPORT + ".tmp"
            with open(tmp, "w") as f:
                f.write(json.dumps(rep))  # (the same text: json.dump would encode in Python, ~10x the C encoder)
            os.replace(tmp, REPORT)

    _stopping = False
    _all_powered = False
