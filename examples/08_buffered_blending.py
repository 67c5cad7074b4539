"""Example 8: three moves in a row without stopping between them (BufferMode blending).

    nc-server &
    plc-run examples/08_buffered_blending.py     # ends by itself after about 3 s

Three MC_MoveAbsolute blocks on X: 0 -> 100 at 200 mm/s, then -> 250 at 100 mm/s with
MC_BlendingNext (the transition at 100 is passed with the velocity of the next move, 100 mm/s),
then -> 300 at 50 mm/s with MC_BlendingPrevious (the transition at 250 with the velocity of the
previous move, 100 mm/s; the third move then slows down to its own 50 mm/s). The NC keeps one
command waiting behind the active one (StateDWord.CmdBuffered; the waiting block is Busy, not
Active), so the third move is started once the second one is the active one - that is, when the
first block reports Done (the successor took over: Done at once, no target window to wait for).
The program prints the velocity with which the axis passes the two transition points: never
zero. Run it on a freshly started nc-server (X at 0).
"""
from plc_client import AXIS_REF, MC_BufferMode, MC_MoveAbsolute, MC_Power

X = AXIS_REF(nc="nc1", axis_id=1, name="X")
MOVES = [  # (Position, Velocity, BufferMode)
    (100.0, 200.0, MC_BufferMode.MC_Aborting),
    (250.0, 100.0, MC_BufferMode.MC_BlendingNext),
    (300.0, 50.0, MC_BufferMode.MC_BlendingPrevious),
]


class Program:
    def __init__(self):
        self.power = MC_Power()
        self.moves = [MC_MoveAbsolute() for _ in MOVES]
        self.execute = [False] * len(MOVES)
        self.passed = {}
        self.last_pos = None
        self.plc = None
        self.steps = self.sequence()

    def cycle(self, plc):
        self.plc = plc
        self.power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
        for fb, ex, (pos, velo, bm) in zip(self.moves, self.execute, MOVES):
            fb(Axis=X, Execute=ex, Position=pos, Velocity=velo, BufferMode=int(bm))
        self.watch_transitions()
        next(self.steps)

    def watch_transitions(self):
        pos = X.NcToPlc.SetPos
        if self.last_pos is not None:
            for p, _, _ in MOVES[:-1]:
                if self.last_pos < p <= pos and p not in self.passed:
                    self.passed[p] = X.NcToPlc.SetVelo
        self.last_pos = pos

    def wait(self, cond, what, timeout=20.0):
        t0 = self.plc.now
        while not cond():
            if self.plc.now - t0 > timeout:
                print(f"gave up waiting for {what}")
                raise SystemExit(1)
            yield

    def check(self, i):
        fb = self.moves[i]
        if fb.Error or fb.CommandAborted:
            print(f"move {i + 1} failed: Error={fb.Error} ErrorID=0x{fb.ErrorID:X} CommandAborted={fb.CommandAborted}")
            raise SystemExit(1)

    def sequence(self):
        yield from self.wait(lambda: self.power.Status, "the enable")
        if abs(X.ActPos) > 0.05:  # start from 0
            print(f"X is at {X.ActPos:.3f}, not at 0: run it on a fresh nc-server")
        self.execute[0] = self.execute[1] = True  # the first moves, the second waits behind it
        yield
        yield from self.wait(lambda: self.moves[0].Active and self.moves[1].Busy and X.Status.CmdBuffered
                             or self.moves[1].Error, "move 2 buffered")
        self.check(1)
        print(f"move 1 active ({self.moves[0].Active}), move 2 waiting (Busy {self.moves[1].Busy}, "
              f"Active {self.moves[1].Active}), StateDWord.CmdBuffered {X.Status.CmdBuffered}")
        yield from self.wait(lambda: not self.moves[0].Busy, "move 1")
        self.check(0)
        print(f"move 1 Done at {X.ActPos:.2f} (move 2 took over: Active {self.moves[1].Active})")
        self.execute[2] = True
        yield
        yield from self.wait(lambda: not self.moves[1].Busy, "move 2")
        self.check(1)
        print(f"move 2 Done at {X.ActPos:.2f}")
        yield from self.wait(lambda: not self.moves[2].Busy, "move 3")
        self.check(2)
        print(f"move 3 Done: X at {X.ActPos:.3f}, in target {X.Status.InTargetPosition}")
        for p, v in sorted(self.passed.items()):
            print(f"passed {p:.0f} mm at {v:.1f} mm/s")
        raise SystemExit(0 if all(v > 0 for v in self.passed.values()) and len(self.passed) == 2 else 1)
