"""Recovery after a router restart or a link cut, on real processes (nc-router, nc-server behind it,
plc-run and a measuring client on 127.0.0.1): how long until the first fresh NC frame at the PLC
and the first accepted command, against a same-run baseline (a fresh client session's first
accepted command). The scenarios and figures are those of tests/znc_testing/failsafe_recovery.py
(also run, once each, by tests/integration/test_failsafe_router.py):

* router:    nc-router SIGKILLed, started again on the same port;
* cut:       the client's link reset (its TCP connections closed, new ones refused) for ~2 s;
* blackhole: the client's link carries nothing for ~2 s (a pulled cable: the leases notice).

Not a test: it prints medians (and the ratio to the baseline, which absorbs how loaded the machine
is) beside the absolute figures.

    .venv/bin/python bench/recovery.py [--runs 3] [--scenario router --scenario cut ...]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from znc_testing.failsafe_recovery import SCENARIOS, measure  # noqa: E402

FIGURES = ("detect", "frame", "claim", "command", "baseline_connect")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="runs per scenario (3)")
    ap.add_argument("--scenario", action="append", choices=SCENARIOS, help="repeatable; default: all")
    args = ap.parse_args(argv)
    results: dict[str, list[dict[str, float]]] = {}
    with tempfile.TemporaryDirectory(prefix="znc-recovery-") as tmp:
        for sc in args.scenario or SCENARIOS:
            for k in range(args.runs):
                results.setdefault(sc, []).append(measure(Path(tmp) / f"{sc}{k}", sc))
    print("\nmedians [ms] (ratio = command accepted / a fresh connection's first accepted command, same run)")
    print(f"{'scenario':>10} " + " ".join(f"{f:>17}" for f in FIGURES) + f" {'ratio':>6}")
    for sc, runs in results.items():
        med = {f: statistics.median(r[f] for r in runs) for f in FIGURES}
        ratio = statistics.median(r["command"] / r["baseline_connect"] for r in runs)
        print(f"{sc:>10} " + " ".join(f"{med[f] * 1e3:17.0f}" for f in FIGURES) + f" {ratio:6.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
