"""deploy/ PLC 2: shares nc1 with PLC 1. Holds nc1 axis 2 (shuttles it) and, now and then, commands
nc1 axis 1, which PLC 1 holds and supplies (any operator may command a claimed axis; the newer
command aborts PLC 1's move, whose program then goes on with its own).

    plc-run plc2.py --client-id plc2 --nc nc1=EP                 # znc-run plc plc2.py in the image
"""
import os

from plc_client import AXIS_REF
from shuttle import Shuttle, env_float

# ZNC_PLC2_VELOCITY: its moves' velocity [u/s] (300; slower moves give a fault injected "during a move" more time)
own = Shuttle(AXIS_REF(nc="nc1", axis_id=2), 0.0, 200.0, velocity=env_float("ZNC_PLC2_VELOCITY", 300.0))
# a move of the shared axis every ZNC_SHARE_S seconds (0: never)
share_period = env_float("ZNC_SHARE_S", 10.0)
shared = Shuttle(AXIS_REF(nc="nc1", axis_id=1), 25.0, 75.0, velocity=100.0, dwell=share_period,
                 power=False) if share_period > 0 else None
if shared is not None:
    shared.hold_until = share_period


def cycle(plc):
    own.cycle(plc.now)
    if shared is not None:
        shared.cycle(plc.now)
