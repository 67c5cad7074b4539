"""Set-point stages: what produces each axis's set-points in a cycle, in an explicit order.

Each stage owns some axes' set-points for the cycle and may read any set-point that an earlier
stage produced in the same cycle. Which stage drives an axis follows its running job: a plan ->
the profile stage; a coupling job -> the coupling stage; an external-generator job -> the
external stage (``JobKind.source``). The superposition stage adds on top of any of them. In the
order of ``NcCore.step`` (``NcCore.pipeline``, :mod:`..pipeline`):

1. :class:`~.profile.ProfileStage` -- every running plan (constant-jerk segments), staggered
   lookahead; then the plans that ended (jobs end, buffered jobs take over).
2. :class:`~.external.ExternalStage` -- set-points fed by the PLC (PLCTONC ExtSetPos/Velo/Acc).
3. :class:`~.superposition.SuperpositionStage` -- the superimposed offsets of the axes that are
   no slaves, then :class:`~.coupling.CouplingStage` level by level (masters before slaves), each
   level followed by its own superimposed offsets; then the limits of slaves and superpositions.
4. job watches and limits, feed enables; the drive; :class:`~.probe.ProbeStage` (the drive's
   position latch); monitoring; NCTOPLC and the job records.
"""
from .coupling import CouplingStage
from .external import ExternalStage
from .probe import ProbeStage
from .profile import ProfileStage
from .superposition import SuperpositionStage

__all__ = ["CouplingStage", "ExternalStage", "ProbeStage", "ProfileStage", "SuperpositionStage"]
