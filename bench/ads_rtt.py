"""ADS through nc-ads, next to raw zenoh, in one run: pyads round trips and a notification's latency from the NC cycle.

Topology: nc-server (default 4 axes, 1 ms) <- zenoh -> nc-ads (its own process, operator) <- AMS/TCP ->
unmodified pyads in this process, all on loopback (nc-ads on its own 127.0.0.x:48898). The raw
references are measured in the same run, in interleaved blocks:

  * raw zenoh RTT:      a client session in this process -> a router process with a trivial queryable
                        (bench/raw_zenoh.py), get + reply, one at a time;
  * zenoh ReadParameter: the same query path to nc-server (what nc-ads itself does for a parameter);
  * ADS state read:     pyads ``read(0x4101, 0, 256 bytes)``: the NCAXISSTATE_ONLINESTRUCT, built by nc-ads
                        from its newest status frame (no zenoh query per read);
  * ADS parameter read: pyads ``read(0x4001, 0x27, LREAL)``: ADS -> nc-ads -> zenoh query -> NC -> back.

Notification latency from the NC cycle: axis 1 moves endlessly (0x4201 IO 0x20 start type 3) so its
NCTOPLC changes every cycle; pyads subscribes ServerOnChange, 1 ms, to 0x4301 IO 0x80 (the 256-byte
NCTOPLC). Its DcTimeStamp (offset 240) is the low 32 bits of the NC time (CLOCK_REALTIME at the cycle's
scheduled start, ns); the callback's CLOCK_REALTIME minus that is the age of the sample when pyads hands
it to Python (NC cycle -> frame -> zenoh -> nc-ads -> server tick -> TCP -> AdsLib -> callback). The
notification's own FILETIME stamp (set by nc-ads when it sends) splits it into NC->sent and sent->callback.
The raw reference: a zenoh subscriber in this process on the frames nc-ads takes (nc/nc1/frame/2ms),
receive time minus the frame's NcTimeNs. Same machine, same clock, so no clock offset enters.

    .venv/bin/python bench/ads_rtt.py [--n 1500] [--seconds 5]
"""
from __future__ import annotations

import argparse
import contextlib
import struct
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgpack
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench.common import Busy, use_this_tree, verdict  # noqa: E402

use_this_tree()  # this checkout and its test helpers (znc_testing), also for nc-server and nc-ads
from bench.noise_floor import floor_line  # noqa: E402
from bench.raw_zenoh import RAW_KEY, raw_queryable  # noqa: E402
from znc_testing import NcTestClient, free_port, start_nc_server, wait_until  # noqa: E402

FILETIME_EPOCH_NS = 11_644_473_600 * 10**9  # 1601-01-01 -> 1970-01-01


def fmt(name: str, xs: np.ndarray, unit: str = "us") -> str:
    if len(xs) == 0:
        return f"{name:>22}: no samples"
    p50, p99 = np.percentile(xs, (50, 99))
    return f"{name:>22}: p50 {p50:8.0f}  p99 {p99:8.0f}  max {xs.max():8.0f} {unit}  (n={len(xs)})"


def nc_time_of(low32: int, now_ns: int) -> int:
    """The full NC time [ns] whose low 32 bits are ``low32``, at most 2^32 ns (4.3 s) before ``now_ns``."""
    t = (now_ns & ~0xFFFFFFFF) | low32
    return t - (1 << 32) if t > now_ns else t


def main() -> int:
    import pyads

    from znc_testing.nc_ads_testing import start_nc_ads

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1500, help="round trips per kind")
    ap.add_argument("--blocks", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=5.0, help="notification measurement time")
    args = ap.parse_args()
    n_block = max(1, args.n // args.blocks)
    floor0, _ = floor_line()
    tmp = Path(tempfile.mkdtemp(prefix="znc-ads-rtt-"))
    res: dict[str, list[float]] = {"raw zenoh RTT": [], "zenoh ReadParameter": [], "ADS 0x4101 state read": [],
                                   "ADS parameter read": []}
    notif_age: list[float] = []
    notif_sent: list[float] = []
    notif_gap: list[float] = []
    raw_age: list[float] = []
    with contextlib.ExitStack() as stack:
        raw_port = stack.enter_context(raw_queryable(free_port()))
        nc = start_nc_server(tmp / "nc")
        stack.callback(nc.kill)
        ads = start_nc_ads(tmp / "ads", nc.endpoint, role="operator", client_id="bench-ads")
        stack.callback(ads.kill)
        raw_cl = NcTestClient(raw_port)
        cl = NcTestClient(nc.port, "bench-zenoh", token=False)
        stack.callback(raw_cl.close)
        stack.callback(cl.close)
        plc = pyads.Connection(ads.netid, 500, ads.host)
        plc.open()
        stack.callback(plc.close)
        wait_until(lambda: plc.read_state()[0] == pyads.ADSSTATE_RUN, 30, "nc-ads RUN", interval=0.05)
        ids = iter(range(10**6, 10**9))
        rp_key = "nc/nc1/axis/1/cmd/read/bench-zenoh"

        def zget(session, key: str, payload: bytes) -> float:  # type: ignore[no-untyped-def]
            t0 = time.perf_counter_ns()
            replies = list(session.get(key, payload=payload, timeout=5.0))
            t1 = time.perf_counter_ns()
            if not replies or replies[0].ok is None:
                raise RuntimeError(f"no reply from {key}")
            return (t1 - t0) / 1000.0

        def ads_read(ig: int, io: int, typ) -> list[float]:  # type: ignore[no-untyped-def]
            """[round trip us], or [] for a read answered with an ADS error (counted by code in ``failed``)."""
            t0 = time.perf_counter_ns()
            try:
                plc.read(ig, io, typ)
            except pyads.ADSError as exc:
                key = (f"0x{ig:04X}/0x{io:X}", int(getattr(exc, "err_code", 0) or 0))
                failed[key] = failed.get(key, 0) + 1
                return []
            return [(time.perf_counter_ns() - t0) / 1000.0]

        state_t = pyads.PLCTYPE_BYTE * 256
        failed: dict[tuple[str, int], int] = {}  # (index group/offset, ADS error code) -> reads answered so
        busy_rt = Busy()
        for _ in range(100):  # warm-up
            zget(raw_cl.session, RAW_KEY, b"x")
            ads_read(0x4101, 0, state_t)
            ads_read(0x4001, 0x27, pyads.PLCTYPE_LREAL)
        for _ in range(args.blocks):
            res["raw zenoh RTT"] += [zget(raw_cl.session, RAW_KEY, b"x") for _ in range(n_block)]
            res["zenoh ReadParameter"] += [zget(cl.session, rp_key, msgpack.packb(
                {"id": next(ids), "cmd": "ReadParameter", "ParameterNumber": 1003})) for _ in range(n_block)]
            res["ADS 0x4101 state read"] += [x for _ in range(n_block) for x in ads_read(0x4101, 0, state_t)]
            res["ADS parameter read"] += [x for _ in range(n_block) for x in ads_read(0x4001, 0x27, pyads.PLCTYPE_LREAL)]

        busy_rt.stop()
        # ---- notification latency on a moving axis ----
        plc.write(0x4301, 0x01, 0x7, pyads.PLCTYPE_UDINT)  # Enable + feed enables (claims axis 1)
        wait_until(lambda: struct.unpack_from("<I", bytes(plc.read(0x4101, 0, state_t)), 104)[0] & (1 << 20), 20,
                   "axis 1 enabled")
        plc.write(0x4201, 0x20, struct.pack("<I4xdd", 3, 0.0, 50.0), pyads.PLCTYPE_BYTE * 24)  # endless plus
        lock = threading.Lock()
        last = [0]

        @plc.notification(None, timestamp_as_filetime=True)
        def on_nctoplc(handle: int, name: str, filetime: int, value: bytearray) -> None:
            now = time.time_ns()
            nc_t = nc_time_of(struct.unpack_from("<I", value, 240)[0], now)
            sent = filetime * 100 - FILETIME_EPOCH_NS
            with lock:
                notif_age.append((now - nc_t) / 1000.0)
                notif_sent.append((sent - nc_t) / 1000.0)
                if last[0]:
                    notif_gap.append((now - last[0]) / 1000.0)
                last[0] = now

        def on_frame(sample) -> None:  # type: ignore[no-untyped-def]
            now = time.time_ns()
            nc_t = struct.unpack_from("<Q", sample.payload.to_bytes(), 16)[0]  # FRAME_HEADER.NcTimeNs
            raw_age.append((now - nc_t) / 1000.0)

        time.sleep(0.5)  # the axis accelerates; then measure
        sub = cl.session.declare_subscriber("nc/nc1/frame/2ms", on_frame)
        attr = pyads.NotificationAttrib(256, pyads.ADSTRANS_SERVERONCHA, 0, 1)
        handles = plc.add_device_notification((0x4301, 0x80), attr, on_nctoplc)
        busy_nt = Busy()
        time.sleep(args.seconds)
        busy_nt.stop()
        plc.del_device_notification(*handles)  # before close (pyads segfaults otherwise)
        sub.undeclare()
        plc.write(0x4201, 0x02, None, None)  # stop
        floor1, _ = floor_line()

    a = {k: np.array(v) for k, v in res.items()}
    print("round trips, one at a time (pyads -> nc-ads -> [zenoh -> nc-server]; raw: zenoh client -> router):")
    for k, v in a.items():
        print(fmt(k, v))
    n_failed = sum(failed.values())
    print(f"ADS reads answered with an error (counted, not measured): {n_failed}"
          + "".join(f"; {where} error {code} (0x{code:X}) x{n}" for (where, code), n in sorted(failed.items())))
    raw50 = float(np.percentile(a["raw zenoh RTT"], 50))
    rp50 = float(np.percentile(a["zenoh ReadParameter"], 50))
    for k in ("ADS 0x4101 state read", "ADS parameter read"):
        p50 = float(np.percentile(a[k], 50))
        print(f"{k:>22}: p50 {p50 / raw50:4.1f}x raw zenoh RTT, {p50 / rp50:4.1f}x zenoh ReadParameter")
    print()
    print("notification latency from the NC cycle (CLOCK_REALTIME at the callback minus the NC time of the "
          "sample's cycle):")
    print(fmt("ADS notification age", np.array(notif_age)))
    print(fmt("  NC cycle -> sent", np.array(notif_sent)))
    print(fmt("  gap between callbacks", np.array(notif_gap)))
    print(fmt("raw zenoh frame age", np.array(raw_age)))
    if notif_age and raw_age:
        print(f"{'':>22}  ADS p50 {np.percentile(notif_age, 50) / np.percentile(raw_age, 50):4.1f}x the raw zenoh "
              "frame age (nc-ads takes nc/nc1/frame/2ms and pushes on-change samples when a frame arrives "
              "(not on its 2 ms tick))")
    print(f"the machine during the round trips: {busy_rt.text()}; during the notifications: {busy_nt.text()}")
    print(f"before: {floor0}")
    print(f"after:  {floor1}")
    verdict("ads_rtt", [], f"{busy_rt.share:.0f} % / {busy_nt.share:.0f} % busy")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
