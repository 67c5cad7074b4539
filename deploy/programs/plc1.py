"""deploy/ PLC 1: axes of BOTH NCs. Holds nc1 axis 1 and nc2 axis 1, shuttles each.

    plc-run plc1.py --client-id plc1 --nc nc1=EP --nc nc2=EP     # znc-run plc plc1.py in the image
"""
from plc_client import AXIS_REF
from shuttle import Shuttle

shuttles = [
    Shuttle(AXIS_REF(nc="nc1", axis_id=1), 0.0, 100.0, velocity=200.0),
    Shuttle(AXIS_REF(nc="nc2", axis_id=1), 0.0, 50.0, velocity=100.0),
]


def cycle(plc):
    for s in shuttles:
        s.cycle(plc.now)
