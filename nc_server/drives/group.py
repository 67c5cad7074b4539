"""Drives of several backends behind one ``DriveABC``: each axis's backend is chosen in the NC's TOML.

The NC core talks to one drive object whose arrays are indexed like its axes. With one backend for every axis
(the common case) :func:`build_drives` returns that backend's object itself: no indirection, no cost. With
several, a :class:`DriveGroup` hands each backend the columns of its axes and gathers what they report, so a
cycle costs one step per backend plus a gather per array.

Configuration (``nc_server.server.config``)::

    [nc]
    drive = "cia402-sim"              # the backend of every axis without a Drive of its own

    [drives.canopen]                  # a backend's shared options (bus, channel, ...): DriveContext.options
    interface = "virtual"
    channel = "nc1"

    [[axis]]
    AxisId = 1
    Drive = { backend = "canopen", node_id = 2 }   # per-axis options go to the backend's from_config

It may import: numpy, nc_server.core.params, nc_server.drives.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ..core.params import AxisParams, ConfigError
from .base import DriveABC, DriveContext


def build_drives(params: Sequence[AxisParams], cycle_time: float, backends: Sequence[str],
                 axis_options: Sequence[Mapping[str, Any]], sections: Mapping[str, Mapping[str, Any]],
                 nc_name: str = "nc1", zenoh: Any = None, axis_ids: Sequence[int] | None = None) -> DriveABC:
    """The drives of every axis, each axis on its configured backend.

    Args:
        params: the axes' parameters in the NC's axis order.
        cycle_time: the NC cycle [s].
        backends: per axis, the backend's entry point name (``"sim"``, ``"cia402-sim"``, ``"canopen"``, ...).
        axis_options: per axis, its ``Drive`` options without ``backend``.
        sections: the ``[drives.<backend>]`` tables.
        nc_name, zenoh, axis_ids: the NC's name, session settings and AxisIds (:class:`.base.DriveContext`).

    Raises:
        ConfigError: a backend refuses its options; its key names the axis (``axis[2].Drive...``) or the
            section (``drives.canopen...``).
        Exception: a backend cannot open its hardware (backends opened before are closed again).
    """
    from . import drive_class  # (the package imports this module)

    if not (len(params) == len(backends) == len(axis_options)):
        raise ValueError("params, backends and axis_options must have one entry per axis")
    order: list[str] = []
    rows: dict[str, list[int]] = {}
    for i, b in enumerate(backends):
        if b not in rows:
            order.append(b)
            rows[b] = []
        rows[b].append(i)
    unused = sorted(set(sections) - set(order))
    if unused:
        raise ConfigError(f"drives.{unused[0]}", "no axis uses this backend (give an axis Drive = "
                                                 f"{{ backend = \"{unused[0]}\", ... }} or remove the section)")
    parts: list[tuple[DriveABC, np.ndarray]] = []
    try:
        for b in order:
            r = rows[b]
            ids = tuple(int(axis_ids[i]) for i in r) if axis_ids is not None else None
            ctx = DriveContext(nc_name=nc_name, options=dict(sections.get(b, {})), zenoh=zenoh, axis_ids=ids)
            try:
                drive = drive_class(b).from_config([params[i] for i in r], cycle_time,
                                                   [axis_options[i] for i in r], ctx)
            except ConfigError as exc:
                raise exc.renamed(_global_key(exc.key, b, r)) from None
            parts.append((drive, np.asarray(r, dtype=np.intp)))
    except BaseException:
        for d, _ in parts:
            d.close()
        raise
    if len(parts) == 1:
        return parts[0][0]
    return DriveGroup(len(params), cycle_time, parts)


def _global_key(key: str, backend: str, rows: Sequence[int]) -> str:
    """A backend's error key in the NC's terms: its axis[k] is the NC's axis[rows[k]], its section drives.<b>."""
    if key.startswith("axis["):
        k, _, rest = key[5:].partition("]")
        try:
            return f"axis[{rows[int(k)]}]{rest}"
        except (ValueError, IndexError):
            return key
    if key == "drives" or key.startswith("drives."):
        tail = key[len("drives"):]
        return key if tail.startswith(f".{backend}") else f"drives.{backend}{tail}"
    return key


class DriveGroup(DriveABC):
    """Several backends, each serving some of the axes (``parts``: the backend and its axis rows).

    Every per-axis array of :class:`DriveABC` is gathered from the parts after each step and after a change
    that can alter it (configure, injected states); methods that name axes are forwarded to the part that
    owns them, with its own row numbers.
    """

    def __init__(self, n: int, cycle_time: float, parts: Sequence[tuple[DriveABC, np.ndarray]]) -> None:
        super().__init__([AxisParams()] * n, cycle_time)
        self.parts = list(parts)
        self.simulated = all(d.simulated for d, _ in self.parts)
        self._owner = np.zeros(n, dtype=np.intp)
        self._local = np.zeros(n, dtype=np.intp)
        for k, (_, r) in enumerate(self.parts):
            self._owner[r] = k
            self._local[r] = np.arange(len(r))
        self._gather()

    @property
    def simulated_axes(self) -> np.ndarray:
        out = np.zeros(len(self.act_pos), dtype=bool)
        for d, r in self.parts:
            out[r] = d.simulated_axes
        return out

    def _gather(self) -> None:
        n = len(self._owner)
        act_pos, act_velo, act_acc = np.empty(n), np.empty(n), np.empty(n)
        # new arrays each cycle, as SimDrive's: the NC may hold last cycle's, its stats read them from another thread
        ready, io_valid, device_error = (np.empty_like(self.ready), np.empty_like(self.io_valid),
                                         np.empty_like(self.device_error))
        following, comm_error, error_code = (np.empty_like(self.following), np.empty_like(self.comm_error),
                                             np.empty_like(self.error_code))
        age = np.empty_like(self.input_age)
        for d, r in self.parts:
            age[r] = d.input_age
            act_pos[r], act_velo[r], act_acc[r] = d.act_pos, d.act_velo, d.act_acc
            ready[r], io_valid[r], device_error[r] = d.ready, d.io_valid, d.device_error
            following[r], comm_error[r], error_code[r] = d.following, d.comm_error, d.error_code
        self.act_pos, self.act_velo, self.act_acc = act_pos, act_velo, act_acc
        self.ready, self.io_valid, self.device_error = ready, io_valid, device_error
        self.following, self.comm_error, self.error_code = following, comm_error, error_code
        self.input_age = age
        self.faulty = any(d.faulty for d, _ in self.parts)

    def _split(self, rows: np.ndarray) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """(part, positions in ``rows``, the part's local rows) for the parts owning some of ``rows``."""
        rows = np.asarray(rows, dtype=np.intp)
        owner = self._owner[rows]
        out = []
        for k in np.unique(owner).tolist():
            pos = np.flatnonzero(owner == k)
            out.append((k, pos, self._local[rows[pos]]))
        return out

    def configure(self, index: int, params: AxisParams) -> None:
        d = self.parts[self._owner[index]][0]
        d.configure(int(self._local[index]), params)
        self._gather()

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        for d, r in self.parts:
            d.step(enabled[r], set_pos[r], set_velo[r], set_acc[r])
        self._gather()

    def resync(self, latched: np.ndarray | None = None) -> None:
        for d, r in self.parts:
            d.resync(None if latched is None else np.asarray(latched, dtype=bool)[r])
        self._gather()

    def reset(self, rows: np.ndarray) -> None:
        for k, _, local in self._split(rows):
            self.parts[k][0].reset(local)

    def set_torque_offset(self, values: np.ndarray) -> None:
        for d, r in self.parts:
            d.set_torque_offset(values[r])

    def torque_fields(self) -> np.ndarray | None:
        got = [(d.torque_fields(), r) for d, r in self.parts]
        if all(f is None for f, _ in got):
            return None
        out = np.zeros((6, len(self._owner)))
        for f, r in got:
            if f is not None:
                out[:, r] = f
        return out

    def terminal_status(self) -> np.ndarray | None:
        got = [(d.terminal_status(), r) for d, r in self.parts]
        if all(f is None for f, _ in got):
            return None
        out = np.zeros(len(self._owner), dtype=np.uint32)
        for f, r in got:
            if f is not None:
                out[r] = f
        return out

    def link_figures(self) -> dict[int, dict[str, Any]]:
        return {int(r[j]): f for d, r in self.parts for j, f in d.link_figures().items()}

    def latch_sync_pulse(self, rows: np.ndarray, prev_pos: np.ndarray) -> np.ndarray:
        out = np.full(len(rows), np.nan)
        for k, pos, local in self._split(rows):
            out[pos] = self.parts[k][0].latch_sync_pulse(local, np.asarray(prev_pos)[pos])
        return out

    def probe_input(self) -> np.ndarray:
        out = np.zeros(len(self._owner), dtype=bool)
        for d, r in self.parts:
            out[r] = d.probe_input()
        return out

    def arm_probe(self, rows: np.ndarray) -> None:
        for k, _pos, local in self._split(rows):
            self.parts[k][0].arm_probe(local)

    def latch_probe(self, rows: np.ndarray, falling: np.ndarray,
                    prev_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        m = len(rows)
        found, pos_out, frac = np.zeros(m, dtype=bool), np.full(m, np.nan), np.full(m, np.nan)
        for k, pos, local in self._split(rows):
            f, p, fr = self.parts[k][0].latch_probe(local, np.asarray(falling)[pos], np.asarray(prev_pos)[pos])
            found[pos], pos_out[pos], frac[pos] = f, p, fr
        return found, pos_out, frac

    def _part(self, index: int) -> tuple[DriveABC, int]:
        if not 0 <= int(index) < len(self._owner):
            raise IndexError(f"no axis index {index}")
        return self.parts[self._owner[index]][0], int(self._local[index])

    def set_probe_signal(self, index: int, level: bool, offset: float) -> None:
        d, j = self._part(index)
        d.set_probe_signal(j, level, offset)

    def set_stall(self, index: int, stall: bool) -> None:
        d, j = self._part(index)
        d.set_stall(j, stall)

    def set_terminal_error(self, index: int, status_word: int) -> None:
        d, j = self._part(index)
        d.set_terminal_error(j, status_word)

    def close(self) -> None:
        for d, _ in self.parts:
            d.close()
