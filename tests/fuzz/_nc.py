"""A real NC for the server-side targets, on virtual time: nc-server's pieces without zenoh.

``NcCore`` from the embedded default configuration (nc1, axes 1-4: soft limits, axis 4 modulo),
``ClaimTable``, ``RequestHandler`` and ``CycleInputs`` wired as ``nc_server.server.app`` wires them.
The handler has a roles map: ``plc1`` (operator: holds and powers the axes, feeds PLCTONC every
cycle), ``plc2`` (operator), ``eng1`` (engineer) and ``obs1`` (observer) have liveliness tokens;
``ghost`` has none and is not in the roles map.

Import this module inside ``atheris.instrument_imports`` (it imports the project).

Checks (a failure raises; see ``_runner.Finding``):

* every reply unpacks to a map with ``id``, ``cmd``, ``error`` (0 or a code of errors.json, never
  0x4000 NC_INTERNAL), ``text`` (str) and ``cycle`` (int);
* no exception is logged (the handler and the core answer their own bugs with 0x4000);
* ``core.step()`` runs, and afterwards every LREAL of NCTOPLC and NCJOBS is finite.
"""
from __future__ import annotations

import copy
import itertools
from typing import Any

import numpy as np

from nc_schema import ERRORS, NCJOBS_DTYPE, NCTOPLC_DTYPE, ControlDWord, ErrorCodes, Keys, make_request, unpack
from nc_server.core import NcCore
from nc_server.server.claims import ClaimTable
from nc_server.server.config import load_config
from nc_server.server.handler import CycleInputs, RequestHandler
from tests.fuzz import _layout
from tests.fuzz._runner import ExceptionLog, Finding

CONFIG = load_config()
AXES: list[int] = [int(c.AxisId) for c in CONFIG.axes]
HOLDER, OTHER, ENGINEER, OBSERVER, GHOST = "plc1", "plc2", "eng1", "obs1", "ghost"
CLIENTS = (HOLDER, OTHER, ENGINEER, OBSERVER, GHOST)
ROLES = {HOLDER: "operator", OTHER: "operator", ENGINEER: "engineer", OBSERVER: "observer"}
ALL_ENABLES = int(ControlDWord.Enable | ControlDWord.FeedEnablePlus | ControlDWord.FeedEnableMinus)
INTERNAL = int(ErrorCodes.NC_INTERNAL)  # type: ignore[attr-defined]
_F8_NCTOPLC = [n for n in NCTOPLC_DTYPE.names if NCTOPLC_DTYPE.fields[n][0].kind == "f"]
_F8_NCJOBS = [n for n in NCJOBS_DTYPE.names if NCJOBS_DTYPE.fields[n][0].kind == "f" and not NCJOBS_DTYPE.fields[n][0].shape]
LOG = ExceptionLog.install()


class Frame:
    """A PLCTONC frame as ``CycleInputs`` takes it (``handler.PlctoncFrame``)."""

    __slots__ = ("arrival", "axis_ids", "plctonc")

    def __init__(self, arrival: float, axis_ids: np.ndarray, plctonc: np.ndarray) -> None:
        self.arrival, self.axis_ids, self.plctonc = arrival, axis_ids, plctonc


def key_table(keys: Keys) -> list[str]:
    """Command keys of every axis (and unknown ones), class and client, plus malformed ones."""
    out: list[str] = []
    for axis in (None, *AXES, 5, 0):
        for cls in _layout.CLASSES:
            for client in CLIENTS:
                out.append(_layout.class_key(keys, axis, cls, client))
    p = keys.prefix
    out += [f"{p}/axis/01/cmd/op/{HOLDER}", f"{p}/axis/1/cmd", f"{p}/axis/-1/cmd/op/{HOLDER}",
            f"{p}/axis/4294967297/cmd/op/{HOLDER}", f"nc/nc2/cmd/read/{HOLDER}", "", f"{p}/axis/1/cmd/op/{HOLDER}/x",
            f"{p}/axis/1/cmd/op/", f"{p}/axis/1/cmd//{HOLDER}", f"{p}/cmd/op", f"{p}/axis/1/cmd/root/{HOLDER}",
            f"{p}/axis/1/cmd/OP/{HOLDER}", f"{p}/axis/1 /cmd/op/{HOLDER}", f"{p}/axis/１/cmd/op/{HOLDER}",
            f"{p}/axis/1/cmd/op/{HOLDER}\n", f"{p}/axis/1/cmd/op/{'x' * 65}", f"{p}/axis/1/cmd/op/pl c",
            f"{p}/axis/1/cmd/op/*", f"{p}/axis/*/cmd/op/{HOLDER}", f"{p}/**/cmd/op/{HOLDER}"]
    return out


class FuzzNc:
    """The NC of one fuzz input.

    Args:
        cycle_time: NC cycle [s].
        held: the axes ``plc1`` claims (through the handler) and powers.
    """

    def __init__(self, cycle_time: float = 0.001, held: list[int] | None = None) -> None:
        self.core = core = NcCore(copy.deepcopy(list(CONFIG.axes)), cycle_time)
        self.claims = ClaimTable(AXES, CONFIG.watchdog_timeout)
        self.keys = Keys(CONFIG.name)
        self.handler = RequestHandler(core, self.claims, self.keys, roles=ROLES,
                                      info_extra=lambda: {"timing": "fuzz", "watchdog_timeout": CONFIG.watchdog_timeout})
        self.inputs = CycleInputs(core, self.claims)
        self.t = 0.0
        self.ids = itertools.count(1)
        for c in (HOLDER, OTHER, ENGINEER, OBSERVER):
            self.handler.client_alive(c)
        #: what plc1 sends every cycle (axis id -> PLCTONC record), while ``feeding``
        self.plc: dict[int, np.void] = {}
        self.feeding = True
        for a in AXES if held is None else held:
            r = self.request(_layout.command_key(self.keys, "Claim", a, HOLDER), make_request("Claim", next(self.ids), HOLDER))
            if r["error"] == 0:
                rec = core.default_plctonc().copy()
                rec["ControlDWord"] = ALL_ENABLES
                self.plc[a] = rec
        self.step()

    def key(self, cmd: str, axis: int | None, client: str = HOLDER) -> str:
        return _layout.command_key(self.keys, cmd, axis, client)

    def request(self, key: str, payload: bytes) -> dict[str, Any]:
        """``RequestHandler.handle`` plus the reply checks; returns the reply map."""
        raw = self.handler.handle(key, payload, self.t)
        LOG.check(f"handling {payload[:200]!r} on {key!r}")
        msg = unpack(raw)
        if not isinstance(msg, dict) or not {"id", "cmd", "error", "text", "cycle"} <= set(msg):
            raise Finding(f"malformed reply {msg!r}")
        err = msg["error"]
        if type(err) is not int or (err != 0 and err not in ERRORS) or err == INTERNAL:
            raise Finding(f"reply error {err!r}: {msg.get('text')!r} (request {payload[:200]!r} on {key!r})")
        if not isinstance(msg["text"], str) or type(msg["cycle"]) is not int:
            raise Finding(f"malformed reply {msg!r}")
        return msg

    def frame(self, client: str = HOLDER) -> Frame:
        ids = np.array(list(self.plc), dtype=np.uint32)
        recs = np.array(list(self.plc.values()), dtype=self.core.plctonc.dtype)
        return Frame(self.t, ids, recs)

    def step(self, n: int = 1, feed: bool = True, frames: list[tuple[str, Any]] | None = None) -> None:
        """``n`` NC cycles; each first applies ``frames`` (default: plc1's, if ``feed`` and feeding) and
        the watchdog, as nc-server's cycle does."""
        for _ in range(n):
            if frames is not None:
                fr = frames
            else:
                f = self.frame() if feed and self.feeding and self.plc else None
                fr = [(HOLDER, f)] if f is not None else []
            self.inputs.apply(fr, self.t)
            LOG.check("applying PLCTONC / watchdog")
            self.core.step()
            self.t += self.core.cycle_time
            LOG.check("in core.step()")
            self.check_outputs()

    def check_outputs(self) -> None:
        """Every LREAL of NCTOPLC and NCJOBS is finite."""
        for arr, names in ((self.core.nctoplc, _F8_NCTOPLC), (self.core.ncjobs, _F8_NCJOBS)):
            for name in names:
                v = arr[name]
                if not np.isfinite(v).all():
                    raise Finding(f"{arr.dtype.names[0]}.. {name} not finite after cycle {self.core.cycle}: {v.tolist()}")
