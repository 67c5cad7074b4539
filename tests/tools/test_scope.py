"""nc-scope against a real NC: it records a move (per-axis keys and the frame), ends cleanly on
SIGINT and on --duration, and its CSV, PNG (rendered and read back) and HTML (parsed, its script
run in node when available) carry the move."""
from __future__ import annotations

import csv
import json
import math
import shutil
import signal
import subprocess
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from znc_testing.tools_testing import T, Rig, kill_group, run_tool, tool_command
from nc_tools import scope
from znc_testing import wait_until

FIELDS = ["SetPos", "ActPos", "SetVelo", "PosDiff"]
C0, C1 = scope.COLORS[0], scope.COLORS[1]


def read_csv(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="") as fh:
        r = csv.DictReader(fh)
        return list(r.fieldnames or []), list(r)


def col(rows: list[dict[str, str]], name: str) -> np.ndarray:
    return np.array([float(r[name]) if r[name] != "" else math.nan for r in rows])


def color_pixels(img: np.ndarray, hex_color: str) -> int:
    """Pixels that are ``hex_color`` blended with at least half of it into the white background
    (an antialiased line's pixels)."""
    e = 1.0 - np.array([int(hex_color[i:i + 2], 16) / 255 for i in (1, 3, 5)])
    d = 1.0 - img[:, :, :3].astype(np.float64)
    alpha = d @ e / (e @ e)
    resid = np.abs(d - alpha[..., None] * e).max(axis=2)
    return int(((alpha > 0.5) & (resid < 0.04)).sum())


def check_png(path: Path, n_fields: int, colors: list[str]) -> np.ndarray:
    import matplotlib.image as mpimg
    img = mpimg.imread(path)
    assert img.shape[:2] == (scope.PNG_BASE_HEIGHT + scope.PNG_FIELD_HEIGHT * n_fields, scope.PNG_WIDTH)
    assert float(img[:, :, :3].std()) > 0.01  # not blank
    for c in colors:  # each axis's line is drawn in its colour
        assert color_pixels(img, c) > 300, c
    return img


class _PageParser(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.scripts: list[tuple[dict[str, Any], str]] = []
        self._in: dict[str, Any] | None = None
        self.canvas_host = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "script":
            self._in = dict(attrs)
            self.scripts.append((self._in, ""))
        if tag == "div" and ("id", "charts") in attrs:
            self.canvas_host = True

    def handle_endtag(self, tag: str) -> None:
        if tag == "script":
            self._in = None

    def handle_data(self, data: str) -> None:
        if self._in is not None:
            a, text = self.scripts[-1]
            self.scripts[-1] = (a, text + data)


def check_html(path: Path, rows: list[dict[str, str]], axes: list[int], fields: list[str]) -> dict[str, Any]:
    text = path.read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text and "src=" not in text  # self-contained
    p = _PageParser()
    p.feed(text)
    p.close()
    assert p.canvas_host
    [data_text] = [t for a, t in p.scripts if a.get("type") == "application/json" and a.get("id") == "scope-data"]
    data = json.loads(data_text)
    assert data["axes"] == axes and data["fields"] == fields
    assert data["cycle"] == [int(r["cycle"]) for r in rows]
    for a in axes:
        for f in fields:
            got = np.array([math.nan if v is None else v for v in data["series"][f"Axis{a}.{f}"]])
            np.testing.assert_array_equal(got, col(rows, f"Axis{a}.{f}"))
    node = shutil.which("node")
    if node:  # run the page's script with a recording stub DOM: it draws every chart, zooms, hovers
        harness = Path(__file__).with_name("scope_page_harness.js")
        out = subprocess.run([node, str(harness), str(path)], capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        rep = json.loads(out.stdout)
        assert rep["charts"] == len(fields) and rep["legendItems"] == len(axes)
        assert rep["initialLineTo"] > 0
        for k, c in enumerate(data["colors"]):
            assert rep["strokesInitial"].count(c) == len(fields), c  # one stroked line per axis and chart
        v0, v1, _, v3 = rep["views"]
        assert v1[1] - v1[0] < v0[1] - v0[0] and v3 == v0  # wheel zoomed in, double-click reset
        if rows:
            assert rep["hover"].startswith("cycle ") and all(f in rep["hover"] for f in fields)
        else:
            assert rep["hover"] == "no samples"
    return data


def test_records_a_move_until_sigint(rig: Rig, tmp_path: Path) -> None:
    rig.enable(1, 3)
    start = float(rig.cl.nctoplc(1)["SetPos"])
    target = start + 40.0
    out = tmp_path / "move"
    p = subprocess.Popen(tool_command("scope", "--connect", rig.endpoint, "--axes", "1,3", "--fields", ",".join(FIELDS),
                                      "--out", str(out)),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        # recording: the per-axis keys are matched once the scope has subscribed; wait for it to
        # have received samples (the NC's own matching: nothing to see from here but its output)
        wait_until(lambda: p.poll() is not None or rig.cl.nctoplc(1) is not None, T, "scope started")
        assert p.stderr is not None
        line = p.stderr.readline()
        assert "recording" in line, line
        line = p.stderr.readline()  # subscribed is not receiving yet (through the router, on a loaded machine)
        assert "first sample received" in line, line
        r = rig.request("MoveAbsolute", axis=1, Position=target, Velocity=40.0)
        wait_until(lambda: float(rig.cl.nctoplc(1)["SetPos"]) == target and float(rig.cl.nctoplc(1)["SetVelo"]) == 0,
                   T, "axis 1 at the target")
        moved = rig.cl.latest("nc/nc1/axis/1/nctoplc")
        assert moved is not None
        seen_after = int.from_bytes(moved[1][:8], "little")  # a cycle after the move, as seen here
        # the scope receives the same samples through the same router: give it 500 NC cycles past
        # that one (seen here) before ending it with SIGINT, so a loaded machine cannot cut it short
        def cycle_here() -> int:
            last = rig.cl.latest("nc/nc1/axis/1/nctoplc")
            return int.from_bytes(last[1][:8], "little") if last is not None else 0
        wait_until(lambda: cycle_here() >= seen_after + 500, T, "the NC 500 cycles past the move")
        p.send_signal(signal.SIGINT)
        stdout, stderr = p.communicate(timeout=T * 2)
    finally:
        kill_group(p)
    assert p.returncode == 0, stderr
    assert "wrote" in stdout and "axis 1:" in stdout and "axis 3:" in stdout
    names, rows = read_csv(out.with_suffix(".csv"))
    assert names[:3] == ["cycle", "time", "nc_time_ns"]
    assert names[3:] == [f"Axis{a}.{f}" for a in (1, 3) for f in FIELDS]
    cycles = np.array([int(r["cycle"]) for r in rows])
    assert len(cycles) > 100 and (np.diff(cycles) > 0).all()  # strictly increasing cycles
    t = col(rows, "time")
    assert t[0] == 0 and (np.diff(t) > 0).all()
    assert cycles[0] < r["cycle"] and cycles[-1] >= seen_after  # the whole move is in it
    sp = col(rows, "Axis1.SetPos")
    ok = ~np.isnan(sp)
    assert sp[ok][0] == pytest.approx(start) and sp[ok][-1] == target
    assert (np.diff(sp[ok]) >= -1e-9).all()  # a positive move: the set-point never goes back
    sv = col(rows, "Axis1.SetVelo")
    assert 39.0 < np.nanmax(sv) <= 40.0 + 1e-9
    i = np.searchsorted(cycles, r["cycle"])  # the move starts at the reply's cycle, not before
    assert (sp[:i][ok[:i]] == pytest.approx(start))
    assert np.nanmax(np.abs(col(rows, "Axis3.SetVelo"))) == 0  # axis 3 stands still
    # lost samples: the summary counts the gaps of each axis's cycles
    for a in (1, 3):
        c = cycles[~np.isnan(col(rows, f"Axis{a}.SetPos"))]
        lost = int((np.diff(c) - 1).sum())
        assert f"axis {a}: {len(c)} samples, {lost} lost" in stdout
    check_png(out.with_suffix(".png"), len(FIELDS), [C0, C1])
    check_html(out.with_suffix(".html"), rows, [1, 3], FIELDS)


def test_duration_from_the_frame_with_a_trigger(rig: Rig, tmp_path: Path) -> None:
    rig.enable(1)
    start = float(rig.cl.nctoplc(1)["SetPos"])
    out = tmp_path / "trig"
    p = subprocess.Popen(tool_command("scope", "--connect", rig.endpoint, "--source", "frame", "--axes", "1",
                                      "--fields", "SetPos,SetVelo", "--trigger", "1.SetVelo>0", "--pre", "0.05",
                                      "--duration", "1.0", "--out", str(out)),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert p.stderr is not None
        wait_until(lambda: "waiting for" in p.stderr.readline(), T, "scope waiting for its trigger")
        r = rig.request("MoveRelative", axis=1, Distance=-5.0, Velocity=20.0)
        assert r["error"] == 0
        # SetVelo goes negative: the trigger (> 0) must not fire on this move
        wait_until(lambda: float(rig.cl.nctoplc(1)["SetPos"]) == start - 5.0, T, "first move done")
        r = rig.request("MoveRelative", axis=1, Distance=5.0, Velocity=20.0)
        stdout, stderr = p.communicate(timeout=T * 2)  # ends by itself, 1 s after the trigger
    finally:
        kill_group(p)
    assert p.returncode == 0, stderr
    _, rows = read_csv(out.with_suffix(".csv"))
    cycles = np.array([int(x["cycle"]) for x in rows])
    assert (np.diff(cycles) > 0).all()
    sv = col(rows, "Axis1.SetVelo")
    trig = int(stdout.split("trigger 1.SetVelo>0: cycle ")[1].split()[0])
    assert cycles[0] < trig <= cycles[-1]
    assert trig >= r["cycle"]  # the negative move did not fire it, the positive one did
    # it fired on the first SetVelo > 0: before it (the --pre window, which may hold the end of the
    # negative move) nothing positive, from it on the positive move
    assert (sv[cycles < trig] <= 0).all() and sv[cycles == trig][0] > 0 and (sv[cycles >= trig] >= 0).all()
    # --duration 1.0 s after the trigger on the scope's clock: about 1000 NC cycles; a scope that lags
    # on a loaded machine records its backlog too, so only "it did stop" is asserted (generously)
    span = (int(rows[-1]["nc_time_ns"]) - int(rows[int(np.searchsorted(cycles, trig))]["nc_time_ns"])) / 1e9
    assert 0.0 < span <= 1.0 + 5.0
    check_png(out.with_suffix(".png"), 2, [C0])
    check_html(out.with_suffix(".html"), rows, [1], ["SetPos", "SetVelo"])


def test_bad_arguments_and_no_samples(rig: Rig, tmp_path: Path) -> None:
    p = run_tool("scope", "--connect", rig.endpoint, "--axes", "1", "--fields", "SetPos,Bogus")
    assert p.returncode == 2 and "Bogus" in p.stderr
    p = run_tool("scope", "--connect", rig.endpoint, "--axes", "1", "--trigger", "2.SetVelo>0")
    assert p.returncode == 2 and "not among --axes" in p.stderr
    out = tmp_path / "none"
    p = run_tool("scope", "--connect", rig.endpoint, "--nc", "nope", "--axes", "1", "--wait", "2", "--out", str(out))
    assert p.returncode == 1 and "no sample" in p.stderr
    names, rows = read_csv(out.with_suffix(".csv"))
    assert rows == [] and names[0] == "cycle"
    check_html(out.with_suffix(".html"), rows, [1], list(scope.DEFAULT_FIELDS))


def test_build_counts_lost_samples_and_nc_skips() -> None:
    from nc_schema import NCTOPLC_DTYPE
    rec = scope.Recorder([1, 2])
    t0 = 1_700_000_000_000_000_000
    for c in range(1, 201):
        for a in (1, 2):
            if a == 2 and 50 <= c < 53:
                continue  # 3 samples of axis 2 lost
            r = np.zeros(1, NCTOPLC_DTYPE)
            r["AxisId"], r["SetPos"] = a, c * a
            rec.add(a, c, t0 + c * 1_000_000 + (4_000_000 if c > 100 else 0), r.tobytes())  # NC skipped 4 deadlines
    r = scope.build(rec, "nc1", ["SetPos"], "axis")
    s = r.summary()
    assert s["rows"] == 200 and s["axes"]["1"]["lost"] == 0
    assert s["axes"]["2"] == {"samples": 197, "first_cycle": 1, "last_cycle": 200, "lost": 3, "gaps": 1,
                              "largest_gap": 3, "restarts": 0}
    assert s["cycle_time_s"] == pytest.approx(0.001) and s["nc_skipped_deadlines"] == 4
    assert np.isnan(r.values[(2, "SetPos")][49:52]).all() and r.values[(2, "SetPos")][52] == 106
