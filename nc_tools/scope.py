"""nc-scope: record NCTOPLC fields of chosen axes at the NC cycle rate, like TwinCAT Scope View.

Every sample is recorded with the NC cycle that produced it: from the per-axis keys
``nc/<nc>/axis/<axis>/nctoplc`` (their ``STAMP`` attachment: u64 Cycle, u64 NcTimeNs; the default)
or from the status frame ``nc/<nc>/frame`` (``--source frame``: one subscription for all axes).
Recording runs for ``--duration`` seconds from the first sample (or from the trigger), or until
Ctrl-C; SIGINT ends it cleanly and everything is still written:

* ``PREFIX.csv``: ``cycle, time, nc_time_ns`` then ``Axis<id>.<field>`` per axis and field (one row
  per NC cycle seen; a value an axis did not deliver in that cycle is empty). ``time`` is the NC
  time since the first row [s] (NcTimeNs: the scheduled start of the cycle).
* ``PREFIX.png``: one panel per field, one line per axis, over time (1200 px wide, 100 px + 250 px
  per field high). Lost samples break the line.
* ``PREFIX.html``: the same as an interactive page, self-contained (inline canvas + script, no
  network): mouse wheel zooms the time axis, drag pans, double-click resets, hovering shows every
  value of the nearest cycle, the legend switches axes on and off. The data are in the page as
  JSON (``<script type="application/json" id="scope-data">``).

Lost samples are reported: cycles missing between the first and the last sample of an axis (the
NC's frame publisher puts only the newest cycle when it falls behind, the link may drop), and,
separately, deadlines the NC itself skipped (NcTimeNs jumps by more than 1.5 cycles).

``--trigger '1.SetVelo>0'`` waits for the condition on an axis's field (``>``, ``<``, ``>=``,
``<=``, ``==``, ``!=``), keeps ``--pre`` seconds before it, and records ``--duration`` after it.

Usage::

    nc-scope --connect tcp/127.0.0.1:7447 --nc nc1 --axes 1,2 --fields SetPos,ActPos,SetVelo,PosDiff \\
             --duration 5 --out move
"""
from __future__ import annotations

import argparse
import bisect
import csv
import datetime as _dt
import html
import json
import math
import operator
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import zenoh

from nc_schema import NCTOPLC_DTYPE, NCTOPLC_SIZE, decode_stamp, frame_records, member_struct

from .common import add_connection_args, open_session

PROG = "nc-scope"
DEFAULT_FIELDS = ("SetPos", "ActPos", "SetVelo", "PosDiff")
#: PNG geometry: width, height of the title/axis band and per field [px] at PNG_DPI
PNG_WIDTH, PNG_BASE_HEIGHT, PNG_FIELD_HEIGHT, PNG_DPI = 1200, 100, 250, 100
#: line colours per axis, in order (matplotlib's tab10; the PNG and the HTML page use the same)
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
          "#bcbd22", "#17becf")
_OPS: dict[str, Callable[[float, float], bool]] = {
    ">=": operator.ge, "<=": operator.le, "==": operator.eq, "!=": operator.ne, ">": operator.gt, "<": operator.lt}
_TRIGGER_RE = re.compile(r"^\s*(\d+)\.(\w+)\s*(>=|<=|==|!=|>|<)\s*(\S+)\s*$")


def recordable_fields() -> list[str]:
    """NCTOPLC fields nc-scope can record: the numeric scalar ones."""
    out = []
    assert NCTOPLC_DTYPE.names is not None and NCTOPLC_DTYPE.fields is not None  # (a struct dtype)
    for name in NCTOPLC_DTYPE.names:
        dt = NCTOPLC_DTYPE.fields[name][0]
        if not name.startswith("_") and dt.shape == () and dt.kind in "iuf":
            out.append(name)
    return out


def _field_reader(name: str) -> Callable[[bytes | memoryview, int], float]:
    off, st = member_struct(NCTOPLC_DTYPE, name)
    return lambda buf, base: float(st.unpack_from(buf, base + off)[0])


@dataclass
class Trigger:
    """A start condition ``<axis>.<field> <op> <value>``.

    Raises:
        ValueError: (from :meth:`parse`) not of that form, or an unknown field.
    """

    axis: int
    field: str
    op: str
    value: float
    text: str

    @classmethod
    def parse(cls, text: str) -> "Trigger":
        m = _TRIGGER_RE.match(text)
        if not m:
            raise ValueError(f"trigger {text!r}: expected <axis>.<field><op><value>, e.g. 1.SetVelo>0")
        if m[2] not in recordable_fields():
            raise ValueError(f"trigger {text!r}: {m[2]} is not a numeric NCTOPLC field")
        try:
            value = float(m[4])
        except ValueError:
            raise ValueError(f"trigger {text!r}: {m[4]!r} is not a number") from None
        return cls(int(m[1]), m[2], m[3], value, text.strip())


class Recorder:
    """Collects (cycle, NcTimeNs, NCTOPLC bytes) per axis; evaluates the trigger as samples arrive.

    ``add`` runs on zenoh's callback thread and does little: an append under a lock, and with a
    trigger one field read.

    Args:
        axes: axis ids to record.
        trigger: start condition (None: record from the first sample).
        pre_s: with a trigger, how much before it to keep [s].
    """

    def __init__(self, axes: list[int], trigger: Trigger | None = None, pre_s: float = 0.0) -> None:
        self.axes = list(axes)
        self.trigger = trigger
        self.pre_ns = int(pre_s * 1e9)
        self.lock = threading.Lock()
        self.samples: dict[int, list[tuple[int, int, bytes]]] = {a: [] for a in self.axes}
        self.unstamped = 0
        self.malformed = 0
        self.first_at: float | None = None  # monotonic time of the first sample [s]
        self.fired_at: float | None = None  # monotonic time the trigger fired [s]
        self.trigger_cycle: int | None = None
        self.trigger_time_ns: int | None = None
        self.got_first = threading.Event()
        self.fired = threading.Event()
        self._read_trig = _field_reader(trigger.field) if trigger else None
        self._op = _OPS[trigger.op] if trigger else None

    def add(self, axis: int, cycle: int, t_ns: int, rec: bytes, base: int = 0) -> None:
        """Record one axis sample (``rec[base:base+256]`` is its NCTOPLC)."""
        data = rec[base:base + NCTOPLC_SIZE] if base or len(rec) != NCTOPLC_SIZE else rec
        with self.lock:
            self.samples[axis].append((cycle, t_ns, data))
            if self.first_at is None:
                self.first_at = time.monotonic()
                self.got_first.set()
        tr = self.trigger
        if tr is not None and self.fired_at is None and axis == tr.axis:
            assert self._read_trig is not None and self._op is not None
            if self._op(self._read_trig(data, 0), tr.value):
                self.trigger_cycle, self.trigger_time_ns = cycle, t_ns
                self.fired_at = time.monotonic()
                self.fired.set()

    # zenoh callbacks ------------------------------------------------------------------------
    def on_axis_sample(self, axis: int) -> Callable[[zenoh.Sample], None]:
        def cb(sample: zenoh.Sample) -> None:
            att = sample.attachment
            try:  # (a STAMP of 24 bytes, protocol 5, or 16 of an older NC)
                cycle, t_ns = decode_stamp(att.to_bytes()) if att is not None else (-1, -1)
            except ValueError:
                cycle = -1
            if cycle < 0:
                self.unstamped += 1
                return
            payload = sample.payload.to_bytes()
            if len(payload) != NCTOPLC_SIZE:
                self.malformed += 1
                return
            self.add(axis, cycle, t_ns, payload)
        return cb

    def on_frame(self, sample: zenoh.Sample) -> None:
        try:
            h, records = frame_records(sample.payload.to_bytes())
        except ValueError:
            self.malformed += 1
            return
        for a in self.axes:
            rec = records.get(a)
            if rec is not None:
                self.add(a, h.Cycle, h.NcTimeNs, rec)

    def prune(self) -> None:
        """Before the trigger: drop what is older than ``pre`` seconds before the newest sample."""
        if self.trigger is None or self.fired_at is not None:
            return
        with self.lock:
            newest = max((s[-1][1] for s in self.samples.values() if s), default=None)
            if newest is None:
                return
            for a, s in self.samples.items():
                k = bisect.bisect_left(s, newest - self.pre_ns, key=lambda x: x[1])
                if k:
                    del s[:k]


@dataclass
class AxisReport:
    """What arrived for one axis: samples, first/last cycle, lost cycles in between, gaps."""

    samples: int = 0
    first_cycle: int | None = None
    last_cycle: int | None = None
    lost: int = 0
    gaps: int = 0
    largest_gap: int = 0
    restarts: int = 0


@dataclass
class Recording:
    """A finished recording, rows merged by NC cycle.

    Attributes:
        cycle: the NC cycles (uint64, increasing), one row each.
        nc_time_ns: NcTimeNs of each row.
        values: ``(axis, field)`` -> float array per row (NaN: that axis has no sample in the row).
    """

    nc: str
    axes: list[int]
    fields: list[str]
    source: str
    cycle: np.ndarray
    nc_time_ns: np.ndarray
    values: dict[tuple[int, str], np.ndarray]
    per_axis: dict[int, AxisReport]
    cycle_time: float | None = None
    nc_skipped: int = 0
    unstamped: int = 0
    malformed: int = 0
    trigger: dict[str, Any] | None = None
    started: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def time(self) -> np.ndarray:
        """Seconds since the first row (NC time)."""
        if not len(self.nc_time_ns):
            return np.zeros(0)
        return (self.nc_time_ns.astype(np.int64) - int(self.nc_time_ns[0])) / 1e9

    def column(self, axis: int, name: str) -> str:
        return f"Axis{axis}.{name}"

    def summary(self) -> dict[str, Any]:
        """JSON-ready counts: rows, cycles, lost samples per axis, NC-skipped deadlines."""
        return {
            "nc": self.nc, "source": self.source, "rows": int(len(self.cycle)),
            "first_cycle": int(self.cycle[0]) if len(self.cycle) else None,
            "last_cycle": int(self.cycle[-1]) if len(self.cycle) else None,
            "duration_s": float(self.time[-1]) if len(self.cycle) else 0.0,
            "cycle_time_s": self.cycle_time, "nc_skipped_deadlines": self.nc_skipped,
            "axes": {str(a): vars(r) for a, r in self.per_axis.items()},
            "unstamped": self.unstamped, "malformed": self.malformed, "trigger": self.trigger,
            "started": self.started, "notes": self.notes,
        }


def build(rec: Recorder, nc: str, fields: list[str], source: str, started: str = "") -> Recording:
    """Merge the recorder's samples by cycle into rows and count what was lost."""
    with rec.lock:
        samples = {a: list(s) for a, s in rec.samples.items()}
    notes: list[str] = []
    if rec.trigger is not None:
        if rec.trigger_time_ns is None:
            notes.append(f"trigger {rec.trigger.text} never fired: the {rec.pre_ns / 1e9:g} s before the end are kept")
        else:
            lo = rec.trigger_time_ns - rec.pre_ns
            samples = {a: [x for x in s if x[1] >= lo] for a, s in samples.items()}
    per_axis: dict[int, AxisReport] = {}
    arrays: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for a, s in samples.items():
        r = AxisReport()
        if s:
            cyc = np.fromiter((x[0] for x in s), dtype=np.uint64, count=len(s))
            # an NC restart starts counting again: keep what came after the last restart
            back = np.flatnonzero(np.diff(cyc.astype(np.int64)) <= 0)
            if back.size:
                r.restarts = int(back.size)
                k = int(back[-1]) + 1
                notes.append(f"axis {a}: the cycle counter went back {back.size} time(s) (NC restart?): "
                             f"only the {len(s) - k} samples after the last one are kept")
                s = s[k:]
                cyc = cyc[k:]
            tns = np.fromiter((x[1] for x in s), dtype=np.uint64, count=len(s))
            recs = np.frombuffer(b"".join(x[2] for x in s), dtype=NCTOPLC_DTYPE)
            arrays[a] = (cyc, tns, recs)
            d = np.diff(cyc.astype(np.int64))
            r.samples, r.first_cycle, r.last_cycle = len(s), int(cyc[0]), int(cyc[-1])
            missing = d[d > 1] - 1
            r.lost, r.gaps = int(missing.sum()), int(missing.size)
            r.largest_gap = int(missing.max()) if missing.size else 0
        per_axis[a] = r
    if arrays:
        cycle = np.unique(np.concatenate([c for c, _, _ in arrays.values()]))
    else:
        cycle = np.zeros(0, dtype=np.uint64)
    nc_time = np.zeros(len(cycle), dtype=np.uint64)
    have = np.zeros(len(cycle), dtype=bool)
    values: dict[tuple[int, str], np.ndarray] = {}
    for a in rec.axes:
        for f in fields:
            values[(a, f)] = np.full(len(cycle), np.nan)
        if a not in arrays:
            continue
        cyc, tns, recs = arrays[a]
        idx = np.searchsorted(cycle, cyc)
        nc_time[idx] = tns
        have[idx] = True
        for f in fields:
            values[(a, f)][idx] = recs[f].astype(np.float64)
    # cycle time and deadlines the NC skipped: from NcTimeNs of consecutive cycles
    cycle_time, skipped = None, 0
    if len(cycle) > 2:
        dc = np.diff(cycle.astype(np.int64))
        dt = np.diff(nc_time.astype(np.int64)) / 1e9
        ok = (dc == 1) & have[1:] & have[:-1]
        if ok.any():
            cycle_time = float(np.median(dt[ok]))
            if cycle_time > 0:
                late = dt[ok] > 1.5 * cycle_time
                skipped = int(np.round(dt[ok][late] / cycle_time - 1).sum())
    trig = None
    if rec.trigger is not None:
        trig = {"condition": rec.trigger.text, "cycle": rec.trigger_cycle,
                "time_s": None if rec.trigger_time_ns is None or not len(cycle)
                else (rec.trigger_time_ns - int(nc_time[0])) / 1e9, "pre_s": rec.pre_ns / 1e9}
    return Recording(nc, list(rec.axes), list(fields), source, cycle, nc_time, values, per_axis, cycle_time,
                     skipped, rec.unstamped, rec.malformed, trig, started, notes)


# ---- output --------------------------------------------------------------------------------------
def write_csv(r: Recording, path: Path) -> None:
    """``cycle, time, nc_time_ns, Axis<id>.<field>...``; a missing value is an empty cell."""
    cols = [(a, f) for a in r.axes for f in r.fields]
    t = r.time
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["cycle", "time", "nc_time_ns"] + [r.column(a, f) for a, f in cols])
        series = [r.values[c] for c in cols]
        for i in range(len(r.cycle)):
            row: list[Any] = [int(r.cycle[i]), f"{t[i]:.6f}", int(r.nc_time_ns[i])]
            for s in series:
                v = s[i]
                row.append("" if math.isnan(v) else repr(float(v)))
            w.writerow(row)


def _title(r: Recording) -> str:
    s = r.summary()
    lost = sum(a["lost"] for a in s["axes"].values())
    span = f"cycles {s['first_cycle']}..{s['last_cycle']}" if s["rows"] else "no samples"
    return f"{r.nc}  axes {', '.join(map(str, r.axes))}  {span}  lost {lost}  NC skipped {r.nc_skipped}"


def write_png(r: Recording, path: Path) -> tuple[int, int]:
    """One panel per field, one line per axis. Returns the image size (width, height) [px]."""
    import matplotlib
    matplotlib.use("Agg", force=True)
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI

    n = max(1, len(r.fields))
    w, h = PNG_WIDTH, PNG_BASE_HEIGHT + PNG_FIELD_HEIGHT * n
    fig = Figure(figsize=(w / PNG_DPI, h / PNG_DPI), dpi=PNG_DPI)
    axs = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    t = r.time
    for ax, f in zip(axs, r.fields or [""]):
        for k, a in enumerate(r.axes):
            if f:
                ax.plot(t, r.values[(a, f)], color=COLORS[k % len(COLORS)], linewidth=1.2, label=f"Axis {a}")
        ax.set_ylabel(f)
        ax.grid(True, alpha=0.3)
        if r.trigger and r.trigger.get("time_s") is not None:
            ax.axvline(r.trigger["time_s"], color="black", linestyle="--", linewidth=0.8)
    axs[0].legend(loc="upper right", fontsize="small")
    axs[-1].set_xlabel("NC time [s]")
    fig.suptitle(_title(r), fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, dpi=PNG_DPI)
    return w, h


def page_data(r: Recording) -> dict[str, Any]:
    """What the HTML page carries: ``{"title", "nc", "axes", "fields", "colors", "cycle", "time",
    "series": {"Axis<id>.<field>": [float|null]}, "summary"}``."""
    def clean(a: np.ndarray) -> list[float | None]:
        return [v if math.isfinite(v) else None for v in a.tolist()]
    return {
        "title": _title(r), "nc": r.nc, "axes": r.axes, "fields": r.fields,
        "colors": [COLORS[k % len(COLORS)] for k in range(len(r.axes))],
        "cycle": [int(c) for c in r.cycle.tolist()], "time": [round(x, 9) for x in r.time.tolist()],
        "series": {r.column(a, f): clean(r.values[(a, f)]) for a in r.axes for f in r.fields},
        "summary": r.summary(),
    }


def write_html(r: Recording, path: Path) -> None:
    """The self-contained interactive page (no network access needed to view it)."""
    data = json.dumps(page_data(r), allow_nan=False, separators=(",", ":")).replace("</", "<\\/")
    page = (_HTML.replace("@TITLE@", html.escape(_title(r)))
            .replace("@DATA@", data).replace("@SCRIPT@", _SCRIPT))
    path.write_text(page, encoding="utf-8")


_HTML = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>nc-scope: @TITLE@</title>
<style>
body { font-family: system-ui, sans-serif; margin: 12px; color: #222; }
h1 { font-size: 15px; font-weight: 600; margin: 0 0 6px 0; }
#help { font-size: 12px; color: #666; margin-bottom: 6px; }
#legend label { margin-right: 14px; font-size: 13px; cursor: pointer; }
#legend .sw { display: inline-block; width: 18px; height: 3px; vertical-align: middle; margin-right: 4px; }
.chart { position: relative; margin-top: 4px; }
.chart canvas { width: 100%; height: 220px; display: block; border: 1px solid #ddd; cursor: crosshair; }
#tip { position: fixed; pointer-events: none; background: rgba(255,255,255,0.95); border: 1px solid #999;
       font: 12px monospace; padding: 4px 6px; display: none; white-space: pre; }
#summary { font: 12px monospace; white-space: pre; color: #444; margin-top: 8px; }
</style></head>
<body>
<h1 id="title">@TITLE@</h1>
<div id="help">wheel: zoom time &middot; drag: pan &middot; double-click: reset &middot; hover: values of the nearest cycle &middot; legend: show/hide an axis</div>
<div id="legend"></div>
<div id="charts"></div>
<div id="tip"></div>
<div id="summary"></div>
<script type="application/json" id="scope-data">@DATA@</script>
<script>
@SCRIPT@
</script>
</body></html>
"""

_SCRIPT = r"""(function () {
"use strict";
var D = JSON.parse(document.getElementById("scope-data").textContent);
var T = D.time, N = T.length, M = {l: 78, r: 12, t: 18, b: 26};
var full = N > 1 && T[N - 1] > T[0] ? [T[0], T[N - 1]] : [0, 1];
var view = full.slice(), hidden = {}, hover = -1, charts = [], drag = null;
function lower(v) { var lo = 0, hi = N; while (lo < hi) { var m = (lo + hi) >> 1; if (T[m] < v) lo = m + 1; else hi = m; } return lo; }
function ticks(lo, hi, n) {
  var span = hi - lo; if (!(span > 0)) { return [lo]; }
  var step = Math.pow(10, Math.floor(Math.log(span / n) / Math.LN10)), err = span / n / step;
  step *= err >= 7.5 ? 10 : err >= 3.5 ? 5 : err >= 1.5 ? 2 : 1;
  var out = []; for (var v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) { out.push(v); } return out;
}
function fmt(v) { if (v === null || v === undefined) { return "-"; } var a = Math.abs(v); return a !== 0 && (a >= 1e6 || a < 1e-3) ? v.toExponential(4) : v.toFixed(4); }
function range(field, i0, i1) {
  var lo = Infinity, hi = -Infinity;
  D.axes.forEach(function (a) {
    if (hidden[a]) { return; }
    var s = D.series["Axis" + a + "." + field];
    for (var i = i0; i < i1; i++) { var v = s[i]; if (v !== null) { if (v < lo) { lo = v; } if (v > hi) { hi = v; } } }
  });
  if (lo === Infinity) { return [-1, 1]; }
  if (hi - lo < 1e-12) { var p = Math.max(Math.abs(lo) * 0.05, 1e-6); return [lo - p, hi + p]; }
  var pad = (hi - lo) * 0.05; return [lo - pad, hi + pad];
}
function draw(ch) {
  var c = ch.canvas, dpr = window.devicePixelRatio || 1;
  var W = c.clientWidth || 900, H = c.clientHeight || 220;
  c.width = Math.round(W * dpr); c.height = Math.round(H * dpr);
  var g = c.getContext("2d"); g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, W, H); g.font = "11px sans-serif";
  var pw = W - M.l - M.r, ph = H - M.t - M.b, x0 = view[0], x1 = view[1];
  var i0 = Math.max(0, lower(x0) - 1), i1 = Math.min(N, lower(x1) + 1), yr = range(ch.field, i0, i1);
  var X = function (t) { return M.l + (t - x0) / (x1 - x0) * pw; };
  var Y = function (v) { return M.t + (1 - (v - yr[0]) / (yr[1] - yr[0])) * ph; };
  ch.X = X; ch.pw = pw;
  g.strokeStyle = "#e4e4e4"; g.fillStyle = "#555"; g.lineWidth = 1;
  ticks(yr[0], yr[1], 5).forEach(function (v) {
    var y = Y(v); g.beginPath(); g.moveTo(M.l, y); g.lineTo(M.l + pw, y); g.stroke();
    g.textAlign = "right"; g.fillText(fmt(v), M.l - 4, y + 4);
  });
  ticks(x0, x1, 8).forEach(function (v) {
    var x = X(v); g.beginPath(); g.moveTo(x, M.t); g.lineTo(x, M.t + ph); g.stroke();
    g.textAlign = "center"; g.fillText(String(+v.toPrecision(6)) + " s", x, H - 8);
  });
  g.textAlign = "left"; g.fillStyle = "#222"; g.fillText(ch.field, M.l + 4, M.t - 5);
  g.save(); g.beginPath(); g.rect(M.l, M.t, pw, ph); g.clip();
  D.axes.forEach(function (a, k) {
    if (hidden[a]) { return; }
    var s = D.series["Axis" + a + "." + ch.field];
    g.strokeStyle = D.colors[k]; g.lineWidth = 1.3; g.beginPath();
    var pen = false;
    if (i1 - i0 > 2 * pw) {        // many samples per pixel: min/max of each pixel column
      var col = -1, lo = 0, hi = 0, any = false;
      var flush = function () { if (any) { var x = M.l + col + 0.5; if (!pen) { g.moveTo(x, Y(hi)); pen = true; } else { g.lineTo(x, Y(hi)); } g.lineTo(x, Y(lo)); } };
      for (var i = i0; i < i1; i++) {
        var v = s[i], cx = Math.floor(X(T[i]) - M.l);
        if (cx !== col) { flush(); col = cx; any = false; }
        if (v === null) { if (any) { flush(); any = false; } pen = false; continue; }
        if (!any) { lo = hi = v; any = true; } else { if (v < lo) { lo = v; } if (v > hi) { hi = v; } }
      }
      flush();
    } else {
      for (var j = i0; j < i1; j++) {
        var w = s[j]; if (w === null) { pen = false; continue; }
        if (!pen) { g.moveTo(X(T[j]), Y(w)); pen = true; } else { g.lineTo(X(T[j]), Y(w)); }
      }
    }
    g.stroke();
  });
  if (D.summary.trigger && D.summary.trigger.time_s !== null) {
    g.strokeStyle = "#000"; g.setLineDash([4, 3]); g.beginPath();
    g.moveTo(X(D.summary.trigger.time_s), M.t); g.lineTo(X(D.summary.trigger.time_s), M.t + ph); g.stroke(); g.setLineDash([]);
  }
  if (hover >= 0 && hover < N) {
    g.strokeStyle = "rgba(0,0,0,0.5)"; g.beginPath(); g.moveTo(X(T[hover]), M.t); g.lineTo(X(T[hover]), M.t + ph); g.stroke();
  }
  g.restore();
  g.strokeStyle = "#999"; g.strokeRect(M.l, M.t, pw, ph);
}
function redraw() { charts.forEach(draw); }
function setView(a, b) {
  var span = full[1] - full[0], minSpan = N > 1 ? (full[1] - full[0]) / N * 4 : 1e-6;
  if (b - a < minSpan) { var m = (a + b) / 2; a = m - minSpan / 2; b = m + minSpan / 2; }
  if (b - a > span) { a = full[0]; b = full[1]; }
  if (a < full[0]) { b += full[0] - a; a = full[0]; }
  if (b > full[1]) { a -= b - full[1]; b = full[1]; }
  view = [a, b]; redraw();
}
function timeAt(ch, px) { return view[0] + (px - M.l) / ch.pw * (view[1] - view[0]); }
function nearest(t) { var i = lower(t); if (i >= N) { i = N - 1; } if (i > 0 && t - T[i - 1] < T[i] - t) { i--; } return i; }
function tipText(i) {
  var lines = ["cycle " + D.cycle[i] + "   t = " + T[i].toFixed(6) + " s"];
  D.fields.forEach(function (f) {
    var parts = D.axes.filter(function (a) { return !hidden[a]; }).map(function (a) { return "Axis" + a + " " + fmt(D.series["Axis" + a + "." + f][i]); });
    lines.push(f + ": " + parts.join("  "));
  });
  return lines.join("\n");
}
var tip = document.getElementById("tip");
function onMove(ch, ev) {
  var r = ch.canvas.getBoundingClientRect(), px = ev.clientX - r.left;
  if (drag) { var dt = (px - drag.px) / ch.pw * (drag.view[1] - drag.view[0]); setView(drag.view[0] - dt, drag.view[1] - dt); }
  if (!N) { return; }
  hover = nearest(timeAt(ch, px)); redraw();
  tip.textContent = tipText(hover); tip.style.display = "block";
  tip.style.left = (ev.clientX + 14) + "px"; tip.style.top = (ev.clientY + 14) + "px";
}
var legend = document.getElementById("legend");
D.axes.forEach(function (a, k) {
  var lab = document.createElement("label"), box = document.createElement("input"), sw = document.createElement("span");
  box.type = "checkbox"; box.checked = true; sw.className = "sw"; sw.style.background = D.colors[k];
  box.addEventListener("change", function () { hidden[a] = !box.checked; redraw(); });
  lab.appendChild(box); lab.appendChild(sw); lab.appendChild(document.createTextNode("Axis " + a)); legend.appendChild(lab);
});
var host = document.getElementById("charts");
D.fields.forEach(function (f) {
  var div = document.createElement("div"), c = document.createElement("canvas"), ch = {field: f, canvas: c};
  div.className = "chart"; div.appendChild(c); host.appendChild(div); charts.push(ch);
  c.addEventListener("wheel", function (ev) {
    ev.preventDefault();
    var r = c.getBoundingClientRect(), t = timeAt(ch, ev.clientX - r.left), k = ev.deltaY > 0 ? 1.25 : 0.8;
    setView(t - (t - view[0]) * k, t + (view[1] - t) * k);
  }, {passive: false});
  c.addEventListener("mousedown", function (ev) { var r = c.getBoundingClientRect(); drag = {px: ev.clientX - r.left, view: view.slice()}; });
  c.addEventListener("mousemove", function (ev) { onMove(ch, ev); });
  c.addEventListener("mouseleave", function () { hover = -1; tip.style.display = "none"; redraw(); });
  c.addEventListener("dblclick", function () { setView(full[0], full[1]); });
});
window.addEventListener("mouseup", function () { drag = null; });
window.addEventListener("resize", redraw);
document.getElementById("summary").textContent = JSON.stringify(D.summary, null, 1);
redraw();
window.ncScope = {data: D, charts: charts, redraw: redraw, setView: setView, view: function () { return view.slice(); },
                  hoverAt: function (t) { if (!N) { return "no samples"; } hover = nearest(t); redraw(); return tipText(hover); }};
})();
"""


# ---- main --------------------------------------------------------------------------------------
def _int_list(text: str) -> list[int]:
    try:
        out = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected axis ids like 1,2") from None
    if not out or any(a < 1 for a in out) or len(set(out)) != len(out):
        raise argparse.ArgumentTypeError(f"{text!r}: expected distinct axis ids >= 1 like 1,2")
    return out


def _fields(text: str) -> list[str]:
    ok = recordable_fields()
    out = [x.strip() for x in text.split(",") if x.strip()]
    bad = [f for f in out if f not in ok]
    if not out or bad or len(set(out)) != len(out):
        raise argparse.ArgumentTypeError(f"unknown or repeated NCTOPLC field(s) {bad or out}; choose from {', '.join(ok)}")
    return out


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog=PROG, description="Record NCTOPLC fields of axes at the NC cycle rate: CSV, PNG, HTML.")
    add_connection_args(p, "zenoh router or NC, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--nc", default="nc1", help="NC name (default nc1)")
    p.add_argument("--axes", type=_int_list, required=True, metavar="IDS", help="axis ids, e.g. 1,2")
    p.add_argument("--fields", type=_fields, default=list(DEFAULT_FIELDS), metavar="NAMES",
                   help=f"NCTOPLC fields (default {','.join(DEFAULT_FIELDS)})")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="seconds to record from the first sample (or the trigger); default: until Ctrl-C")
    p.add_argument("--out", default=None, metavar="PREFIX",
                   help="writes PREFIX.csv, PREFIX.png, PREFIX.html (default scope-<nc>-<date>-<time>)")
    p.add_argument("--source", choices=("axis", "frame"), default="axis",
                   help="axis: the per-axis nctoplc keys (default); frame: nc/<nc>/frame")
    p.add_argument("--no-png", action="store_true", help="do not write the PNG")
    p.add_argument("--no-html", action="store_true", help="do not write the HTML page")
    p.add_argument("--trigger", type=str, default=None, metavar="COND",
                   help="start at <axis>.<field><op><value>, e.g. 1.SetVelo>0 (op: > < >= <= == !=)")
    p.add_argument("--pre", type=float, default=0.1, metavar="S", help="with --trigger: seconds kept before it (default 0.1)")
    p.add_argument("--wait", type=float, default=10.0, metavar="S",
                   help="give up when no sample arrives within this many seconds (default 10)")
    a = p.parse_args(argv)
    if a.duration is not None and a.duration <= 0:
        p.error("--duration must be > 0")
    if a.pre < 0 or a.wait <= 0:
        p.error("--pre must be >= 0 and --wait > 0")
    if a.trigger is not None:
        try:
            a.trigger = Trigger.parse(a.trigger)
        except ValueError as exc:
            p.error(str(exc))
        if a.trigger.axis not in a.axes:
            p.error(f"the trigger's axis {a.trigger.axis} is not among --axes")
    return a


def main(argv: list[str] | None = None) -> int:
    """Run nc-scope; returns the exit status (0 written, 1 no samples, 2 no connection)."""
    a = parse_args(argv)
    stop = threading.Event()

    def on_sigint(signum: int, frame: Any) -> None:
        stop.set()
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # a second Ctrl-C ends at once

    prev = signal.signal(signal.SIGINT, on_sigint)
    prev_term = signal.signal(signal.SIGTERM, on_sigint)
    started = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    prefix = a.out or f"scope-{a.nc}-{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}"
    rec = Recorder(a.axes, a.trigger, a.pre)
    session = open_session(a.connect, PROG, a.tls_dir, a.client_id)
    subs: list[Any] = []
    try:
        if a.source == "axis":
            for ax in a.axes:
                subs.append(session.declare_subscriber(f"nc/{a.nc}/axis/{ax}/nctoplc", rec.on_axis_sample(ax)))
        else:
            subs.append(session.declare_subscriber(f"nc/{a.nc}/frame", rec.on_frame))
        what = f"nc/{a.nc}/frame" if a.source == "frame" else ", ".join(f"nc/{a.nc}/axis/{x}/nctoplc" for x in a.axes)
        print(f"{PROG}: recording {what} ({'Ctrl-C ends' if a.duration is None else f'{a.duration:g} s'})",
              file=sys.stderr, flush=True)
        deadline = time.monotonic() + a.wait
        while not rec.got_first.is_set() and not stop.is_set() and time.monotonic() < deadline:
            rec.got_first.wait(0.1)
        if not rec.got_first.is_set():
            if not stop.is_set():
                print(f"{PROG}: no sample from {what} within {a.wait:g} s", file=sys.stderr)
        else:
            # (a script that starts a motion to record waits for this line: "recording" only says subscribed)
            print(f"{PROG}: first sample received", file=sys.stderr, flush=True)
            if a.trigger is not None:
                print(f"{PROG}: waiting for {a.trigger.text}", file=sys.stderr, flush=True)
                while not rec.fired.is_set() and not stop.is_set():
                    rec.fired.wait(0.2)
                    rec.prune()
            t0 = rec.fired_at if a.trigger is not None and rec.fired_at is not None else rec.first_at
            assert t0 is not None
            while not stop.is_set():
                left = None if a.duration is None else t0 + a.duration - time.monotonic()
                if left is not None and left <= 0:
                    break
                stop.wait(0.2 if left is None else min(0.2, left))
    finally:
        for s in subs:
            try:
                s.undeclare()
            except Exception:
                pass
        try:
            session.close()
        except Exception:
            pass
        signal.signal(signal.SIGINT, prev)
        signal.signal(signal.SIGTERM, prev_term)
    r = build(rec, a.nc, a.fields, a.source, started)
    written = []
    csv_path = Path(prefix + ".csv")
    write_csv(r, csv_path)
    written.append(str(csv_path))
    if not a.no_png:
        write_png(r, Path(prefix + ".png"))
        written.append(prefix + ".png")
    if not a.no_html:
        write_html(r, Path(prefix + ".html"))
        written.append(prefix + ".html")
    s = r.summary()
    print(f"{PROG}: {s['rows']} rows" + (f", cycles {s['first_cycle']}..{s['last_cycle']} ({s['duration_s']:.3f} s NC time)"
                                         if s["rows"] else ""))
    for ax, ar in s["axes"].items():
        print(f"  axis {ax}: {ar['samples']} samples, {ar['lost']} lost in {ar['gaps']} gap(s)"
              + (f", largest {ar['largest_gap']} cycles" if ar["gaps"] else ""))
    if r.cycle_time:
        print(f"  NC cycle {r.cycle_time * 1e3:.3f} ms, {r.nc_skipped} deadline(s) skipped by the NC")
    if r.unstamped or r.malformed:
        print(f"  ignored: {r.unstamped} without STAMP, {r.malformed} malformed")
    if r.trigger:
        print(f"  trigger {r.trigger['condition']}: " + ("cycle %s" % r.trigger["cycle"] if r.trigger["cycle"] else "not fired"))
    for n in r.notes:
        print(f"  note: {n}")
    print(f"  wrote {', '.join(written)}")
    return 0 if s["rows"] else 1


if __name__ == "__main__":
    sys.exit(main())
