"""The idle ``plc-run`` program of bench/many_clients.py: no axes, no blocks, nothing per cycle.

``plc-run bench/idle_program.py`` is a PLC client that is connected to its NC (session, liveliness token,
the NC's frames) and runs its 10 ms task without a program: the reference the CPU of a working plc-run is
compared with in the same run ("CPU per plc-run <= 2x an idle plc-run", issue 19).
"""


def cycle(plc) -> None:  # type: ignore[no-untyped-def]
    pass
