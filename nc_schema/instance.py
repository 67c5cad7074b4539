"""NC restart detection: the one rule every client applies (PLC runtime, nc-ads, nc-status).

A restart is a new NC *process instance*. Two kinds of evidence show one:

1. **The instance token.** Every nc-server process declares, besides ``nc/<nc>/alive``, the liveliness
   token ``nc/<nc>/alive/<instance>`` (``Keys.alive_instance``), ``<instance>`` an id of that process
   (:func:`new_instance_id`). A token with an id other than the one a client follows is a new instance
   (:meth:`NcInstance.token`). The token flaps like ``nc/<nc>/alive``: zenoh drops a link (and every token
   behind it) when either side hears nothing for the other's lease (500 ms here: a starved or SIGSTOPped
   client, NC or router on a loaded machine) and reconnects 0.1-0.3 s later - it then comes back with
   the *same* id, which is no restart.
2. **The frames** (:meth:`NcInstance.frame`): a ``Cycle`` below the previous frame's (an instance counts
   its cycles from 1). The only evidence an older NC (no instance token) gives, and not enough alone: a
   new instance whose first frame a client sees with a *higher* Cycle than the old instance's last (the
   old one ran briefly; the new one counted cycles while its frame publisher child was starting or
   while the client stood still) shows nothing in the frames.

The NC's ``nc/<nc>/alive`` going away is no evidence at all: it means "unreachable" (the clients' data
turns invalid), never "restarted".

One restart is one step of ``restarts`` whichever evidence arrives first:

* frames first (the cycle went back: counted), then the token: the next new id is that instance
  (adopted, not counted again);
* token first (counted), then frames: a cycle going back within the next :data:`FRAMES_OWED` frames is
  that same instance's first frame (not counted again). A client may still take one or two frames of
  the old instance after the new token (its RingChannel(1), nc-ads's frame thread holding one), so the
  old instance's frames do not end the wait; a new instance's first frame comes right after them.

**The epoch** (protocol 5, :meth:`NcInstance.take`): a hot-standby pair (docs/standby.md) is one NC instance
(the standby holds the active NC's instance token, its Cycle count continues the active one's), and every frame
carries the epoch of the NC that sent it (0 without redundancy). After a link cut or a freeze the old active NC,
back on the network, publishes its own frames (its own Cycle count and set-points) until it sees its successor's
higher epoch. Hence a client follows the highest epoch seen of the instance:

* a frame of a higher epoch is taken at once (a takeover: ``epoch_rises``); the restart rule above then applies
  as to any frame: a Cycle count that continues is no restart; one that went back is (the successor did not know
  the cycles the client saw last: the commands of those cycles are lost with them);
* a frame of a lower epoch is dropped (``stale_frames``): no data, no restart evidence, the Cycle followed stays;
* a lower epoch is taken (``epoch_falls``; the restart rule applies to it) only when (a) a new instance token was
  seen since the last frame of another epoch or of a Cycle going back was taken (the whole pair, or the NC,
  restarted: a new instance may start again at epoch 0), or (b) for :data:`EPOCH_HOLD_S` only frames of lower epochs
  came (the first one dropped and the last one taken both that long ago; callers that pass ``now``; a client that
  stalled itself for that long does not take the old NC's next frame): the higher-epoch NC is gone for good and the lower one is all
  there is (an old active NC demotes itself within the takeover limit, at most ~1 s, once it sees its successor; 2 s
  of its frames were seen after a link cut: the hold is well beyond that, and short enough not to leave a client
  blind for long).

Decisions: no rule on ``NcTimeNs`` (an earlier rule 2 took "NC time ran on by > 5 s and more than the
whole Cycle count takes" as a new instance: an NC that ran 1 s and then stood 6 s on a loaded machine
met it while it was the same instance - a false restart stops axes nobody wanted stopped; the instance
token covers what it was for). The first id a client sees is adopted without a restart: the client
starts following that NC. Pure (no zenoh, no clock): the caller passes the frames' ``Cycle`` and the
token ids.
"""
from __future__ import annotations

import os
import re

#: A cycle going back within this many frames after a new instance token is that instance's (see above).
FRAMES_OWED = 3
#: A new instance token within this many frames after the frames showed a restart (the cycle went back) is
#: that restart's: tokens come within milliseconds of the first frames; an NC that declares none (an older
#: one) never sends it, and a later restart announced by its token first must still count.
TOKEN_OWED_FRAMES = 200

#: A lower epoch than the one followed is taken after this long of lower-epoch frames only, none of the epoch
#: followed in between [s] (see above: a client that stalled sees no silence, only the old node's frames).
EPOCH_HOLD_S = 5.0

#: An instance id: 16 lowercase hex digits (:func:`new_instance_id`).
INSTANCE_RE = re.compile(r"[0-9a-f]{16}")


def new_instance_id() -> str:
    """A new NC process instance id: 16 hex digits from ``os.urandom(8)``.

    Random rather than start time + pid: pids repeat (pid 1 in every container), wall clocks jump, and
    2^64 ids make two instances of one NC share one by chance practically impossible. It tells nothing
    about the host.
    """
    return os.urandom(8).hex()


class NcInstance:
    """Which NC instance one client follows (see the module docstring); not thread-safe.

    Attributes:
        instance: the instance id followed (None: no instance token seen: an older NC, or not yet).
        cycle: ``Cycle`` of the newest frame (None before the first).
        restarts: how many new instances were seen.
        epoch: the epoch followed (:meth:`take`; None before the first frame).
        stale_frames: frames dropped for a lower epoch than the one followed.
        epoch_rises, epoch_falls: higher epochs taken (takeovers seen), lower ones taken (see the module docstring).
    """

    __slots__ = ("instance", "cycle", "restarts", "_frames_owed", "_token_owed", "epoch", "stale_frames",
                 "epoch_rises", "epoch_falls", "_epoch_seen", "_epoch_open", "_stale_since")

    def __init__(self) -> None:
        self.instance: str | None = None
        self.cycle: int | None = None
        self.restarts = 0
        #: frames during which a cycle going back is the restart a new token already counted
        self._frames_owed = 0
        #: frames during which a new instance token is the restart the frames already counted (its token
        #: comes within milliseconds; an NC without one never sends it: then the wait ends)
        self._token_owed = 0
        self.epoch: int | None = None
        self.stale_frames = 0
        self.epoch_rises = 0
        self.epoch_falls = 0
        #: when the newest frame of the epoch followed was taken (the caller's clock; None: no time given)
        self._epoch_seen: float | None = None
        #: a new instance token since: the next frame of another epoch sets the epoch, even a lower one
        self._epoch_open = False
        #: when the first frame of a lower epoch was dropped since the last frame taken (None: none since): the
        #: EPOCH_HOLD_S rule needs that long of lower-epoch frames only, not merely a silence of the followed
        #: epoch (a client that stalled for 5 s must not take the old node's next frame and then see the real
        #: active NC's Cycle count as gone back)
        self._stale_since: float | None = None

    def take(self, cycle: int, epoch: int = 0, now: float | None = None) -> tuple[bool, str | None]:
        """Take a frame's ``Cycle`` and ``Epoch`` (the epoch rule of the module docstring, then :meth:`frame`).

        Args:
            now: the caller's monotonic clock [s], for the :data:`EPOCH_HOLD_S` rule (None: that rule is off).

        Returns:
            (taken, reason): taken False for a frame of a lower epoch that is dropped (its data must not be used;
            reason None); else the reason of a restart as :meth:`frame` gives it, or None.
        """
        epoch = int(epoch)
        followed = self.epoch
        if followed is not None and epoch != followed:
            if epoch > followed:
                self.epoch_rises += 1
            elif self._epoch_open or (now is not None and self._epoch_seen is not None
                                      and self._stale_since is not None
                                      and now - max(self._epoch_seen, self._stale_since) >= EPOCH_HOLD_S):
                self.epoch_falls += 1
            else:
                self.stale_frames += 1
                if now is not None and self._stale_since is None:
                    self._stale_since = now
                return False, None
            self._epoch_open = False
        self.epoch = epoch
        self._stale_since = None
        if now is not None:
            self._epoch_seen = now
        return True, self.frame(cycle)

    def frame(self, cycle: int) -> str | None:
        """Take a frame's ``Cycle``.

        Returns:
            None for the same instance; for a new one the reason (for the log), counted in ``restarts``.
        """
        cycle = int(cycle)
        why = None
        if self.cycle is not None and cycle < self.cycle:
            self._epoch_open = False  # (a new instance's first frame: its epoch is the one to follow)
            if self._frames_owed:
                self._frames_owed = 0  # the new instance's first frame: its token counted it
            else:
                why = "its cycle counter went back"
                self.restarts += 1
                self._token_owed = TOKEN_OWED_FRAMES
        else:
            if self._frames_owed:
                self._frames_owed -= 1
            if self._token_owed:
                self._token_owed -= 1
        self.cycle = cycle
        return why

    def token(self, instance: str) -> str | None:
        """Take the id of an instance token that appeared (a liveliness PUT of ``nc/<nc>/alive/<instance>``).

        Returns:
            None for the instance followed (a token that came back), the first id seen, or the instance
            the frames already showed; else the reason (for the log), counted in ``restarts``.

        Raises:
            ValueError: ``instance`` is not an instance id (callers drop such tokens before).
        """
        if not isinstance(instance, str) or not INSTANCE_RE.fullmatch(instance):
            raise ValueError(f"not an NC instance id: {instance!r}")
        old, self.instance = self.instance, instance
        if old is None or instance == old:
            self._token_owed = 0
            return None
        if self._token_owed:  # the frames showed this restart first (its frames are taken: no epoch to open)
            self._token_owed = 0
            return None
        self._epoch_open = True  # (a new instance: it may run at a lower epoch, see take)
        self.restarts += 1
        self._frames_owed = FRAMES_OWED
        return f"a new instance {instance} (was {old})"
