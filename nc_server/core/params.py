"""Axis parameters with their TwinCAT names (MC_AxisPara), units and validation.

Units are the axis's own (e.g. mm or degrees): velocities in units/s, accelerations
in units/s^2, jerk in units/s^3, times in seconds.

Which MC_AxisPara number reads/writes which field, the valid ranges and when a write is allowed come
from the parameter table ``schema/params.json`` (``nc_schema.PARAMETERS``): a field that a table entry
stores is validated by that entry's range (the configuration and WriteParameter alike); the other fields
(Sim*, Modulo, Homed, ...) by their kind here.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field, fields, replace
from typing import Any, Mapping

from nc_schema import PARAMETERS, ErrorCodes, NcError, ParamEntry, error_name


class ConfigError(ValueError):
    """An invalid configuration value: ``key: message`` (``[0x070B ADSERR_DEVICE_INVALIDPARM]`` appended
    when ``code`` is given).

    Codes (zenoh-nc choice): an axis entry that the NC would refuse the same way at run time carries the
    code it gets there, whatever the source (config file, overlay, ``--set``): a parameter value of the
    wrong type or out of range 0x070B (what MC_WriteParameter answers; a bad value of a parameter whose
    table entry names TwinCAT's own code, e.g. AxisLoopingDistance 0x4328, that code), an unknown parameter name 0x0703
    (what an undefined MC_AxisPara number gets), an AxisId that is not configured or not 1..65535 0x4012
    (NC_AXIS_ID_NOT_ALLOWED). Keys TwinCAT has no error code for (``[nc]``, ``[zenoh]``, files, TOML
    syntax, a duplicate axis) carry none.

    Attributes:
        key: the offending key, e.g. ``axis[2].AxisVeloMax``.
        message: what is wrong, without the key and the code.
        code: the TwinCAT error code, or None.
    """

    def __init__(self, key: str, message: str, code: int | None = None) -> None:
        tail = f" [0x{code:04X} {error_name(code)}]" if code is not None else ""
        super().__init__(f"{key}: {message}{tail}")
        self.key = key
        self.message = message
        self.code = code

    def renamed(self, key: str) -> ConfigError:
        """The same error under another key (where the value came from)."""
        return ConfigError(key, self.message, self.code)


def _p(default: Any, kind: str, doc: str) -> Any:
    """A parameter field; ``kind`` is checked by ``_check``: "bool", "pos" (> 0), "nonneg" (>= 0), "real" (finite),
    "mask" (2^k - 1, k = 1..32),
    "int" (a whole number, held as a float: MC_AxisPara carries it as an LREAL)."""
    return field(default=default, metadata={"kind": kind, "doc": doc})


@dataclass
class AxisParams:
    """Parameters of one axis. Field names are the TwinCAT MC_AxisPara names."""

    AxisVeloMax: float = _p(1000.0, "pos", "maximum permitted velocity [u/s]")
    AxisAcc: float = _p(5000.0, "pos", "default acceleration [u/s^2]")
    AxisDec: float = _p(5000.0, "pos", "default deceleration [u/s^2]")
    AxisJerk: float = _p(50000.0, "pos", "default jerk [u/s^3]")
    AxisRapidTraverseVelocity: float = _p(500.0, "pos", "rapid traverse velocity [u/s]")
    AxisVeloManSlow: float = _p(50.0, "pos", "manual velocity slow (jog) [u/s]")
    AxisVeloManFast: float = _p(250.0, "pos", "manual velocity fast (jog) [u/s]")
    AxisCalibrationVelocityForward: float = _p(10.0, "pos", "homing velocity towards the cam [u/s]")
    AxisCalibrationVelocityBackward: float = _p(5.0, "pos", "homing velocity off the cam [u/s]")
    AxisCalibrationValue: float = _p(0.0, "real", "reference position set by MC_Home when Position is DEFAULT_HOME_POSITION [u]")
    AxisInvertCalibrationCamSearchDirection: bool = _p(
        True, "bool", "TwinCAT 'Invert direction of calibration cam search': True = search the cam in negative direction")
    AxisInvertSyncPulseSearchDirection: bool = _p(
        False, "bool", "TwinCAT 'Invert direction towards sync impulse': False = leave the cam in positive direction")
    AxisJogIncrementForward: float = _p(
        1.0, "nonneg", "inching distance forward [u] (MC_AxisPara 1013): MC_Jog MC_JOGMODE_INCHING(_MODULO) with "
        "Position 0 moves forward by it; 0: such a jog is refused (0x4B06; E_JogMode, "
        "https://infosys.beckhoff.com/content/1033/tcplclib_tc2_mc2/70142987.html). Bad value: 0x4314 (TwinCAT's "
        "'pulse width in positive direction', taken to be this parameter)")
    AxisJogIncrementBackward: float = _p(
        1.0, "nonneg", "inching distance backward [u] (MC_AxisPara 1014): as AxisJogIncrementForward, backward. Bad "
        "value: 0x4315 (TwinCAT's 'pulse width in negative direction')")
    AxisEnMinSoftPosLimit: bool = _p(False, "bool", "minimum software limit enabled")
    AxisMinSoftPosLimit: float = _p(-1000.0, "real", "minimum software limit [u]")
    AxisEnMaxSoftPosLimit: bool = _p(False, "bool", "maximum software limit enabled")
    AxisMaxSoftPosLimit: float = _p(1000.0, "real", "maximum software limit [u]")
    AxisEnPositionLagMonitoring: bool = _p(True, "bool", "following error (position lag) monitoring enabled")
    AxisMaxPosLagValue: float = _p(5.0, "pos", "maximum position lag [u]")
    AxisMaxPosLagFilterTime: float = _p(0.02, "nonneg", "time the lag may exceed the maximum before 0x4550 [s]")
    AxisEnPositionRangeMonitoring: bool = _p(True, "bool", "position range monitoring enabled (InPositionArea)")
    AxisPositionRangeWindow: float = _p(5.0, "pos", "position range window [u]")
    AxisEnTargetPositionMonitoring: bool = _p(True, "bool", "target position monitoring enabled (InTargetPosition)")
    AxisTargetPositionWindow: float = _p(0.02, "pos", "target position window [u]")
    AxisTargetPositionMonitoringTime: float = _p(0.02, "nonneg", "time inside the window before InTargetPosition [s]")
    AxisEnInTargetTimeout: bool = _p(False, "bool", "PEH time monitoring enabled (0x435C)")
    AxisInTargetTimeout: float = _p(5.0, "pos", "PEH time: target window must be reached within [s]")
    AxisEnMotionMonitoring: bool = _p(
        False, "bool", "motion monitoring enabled: 0x435D when the actual position moves less than "
        "AxisMotionMonitoringWindow within AxisMotionMonitoringTime while the axis should move (monitoring.py)")
    AxisMotionMonitoringWindow: float = _p(0.1, "pos", "motion monitoring window [u]")
    AxisMotionMonitoringTime: float = _p(0.5, "pos", "motion monitoring time [s]")
    # the set-point / actual position chain (corrections.py)
    AxisDelayTimeVeloPosition: float = _p(
        0.0, "nonneg", "dead time between set-point and actual position: the controller and PosDiff use the set "
        "position this long ago (whole NC cycles, rounded; at most 0.1) [s]")
    AxisEnBacklashCompensation: bool = _p(
        False, "bool", "backlash compensation: AxisBacklash added on the negative side at each reversal")
    AxisBacklash: float = _p(0.0, "nonneg", "backlash (play) compensated by AxisEnBacklashCompensation [u]")
    AxisEnActPosCorrection: bool = _p(
        False, "bool", "actual position correction: PLCTONC.PositionCorrection added to the actual position")
    AxisActPosCorrectionFilterTime: float = _p(
        0.0, "nonneg", "P-T1 filter time of the actual position correction (0: unfiltered) [s]")
    AxisEncoderModuloValue: float = _p(360.0, "pos", "modulo factor (period) for Modulo* positions [u]")
    AxisModuloToleranceWindow: float = _p(0.0, "nonneg", "modulo tolerance window (TcMC 3.5) [u]")
    Modulo: bool = _p(False, "bool", "modulo axis (OpModeDWord.OpModeModulo, modulo display)")
    AxisAllowMotionCmdToSlave: bool = _p(
        False, "bool", "TwinCAT 'Allow motion commands to slave axis' (OpModeDWord.OpModeAllowSlaveCommands): a motion "
        "command to a coupled slave decouples it (Aborting only); off: refused with 0x4266")
    AxisAllowMotionCmdToExtSetAxis: bool = _p(
        False, "bool", "TwinCAT 'Allow motion commands to external setpoint axis' (OpModeDWord.OpModeAllowExtSetAxisCommands): "
        "a motion command disables the external set-point generator; off: refused with 0x4B08")
    # the encoder chain of the simulated drive (nc_server/drives/encoder.py):
    # ActPos = +-(increments & AxisEncoderEncoderMask) * AxisEncoderScalingFactor + AxisEncoderOffset
    AxisEncoderScalingFactor: float = _p(1.0, "pos", "encoder scaling factor [u/inc]")
    AxisEncoderOffset: float = _p(0.0, "real", "encoder position offset [u]")
    AxisEncoderDirectionInverse: bool = _p(False, "bool", "encoder counting direction inverted")
    AxisEncoderEncoderMask: float = _p(4294967295.0, "mask", "encoder mask (maximum encoder value), 2^k - 1 [inc]")
    SimTimeConstant: float = _p(0.001, "nonneg", "simulated drive: first-order position lag [s]")
    SimSyncPulseSpacing: float = _p(1.0, "pos", "simulated encoder: distance between sync (zero) pulses [u]")
    SimSyncPulseOffset: float = _p(0.0, "real", "simulated encoder: position of one sync pulse [u]")
    SimProbePeriod: float = _p(
        0.0, "nonneg", "simulated touch probe sensor (input 1): TRUE while ((drive position - SimProbeOffset) mod "
        "SimProbePeriod) < SimProbeWidth, a pattern repeating every SimProbePeriod; 0 = no sensor, the input is "
        "only set by simulated probe signals [u]")
    SimProbeOffset: float = _p(0.0, "real", "simulated touch probe sensor: start of one TRUE window (drive position) [u]")
    SimProbeWidth: float = _p(
        0.0, "nonneg", "simulated touch probe sensor: length of each TRUE window (0: never TRUE, >= SimProbePeriod: "
        "always TRUE) [u]")
    SimStepper: bool = _p(
        False, "bool", "simulated drive: a stepper motor on a KL2531/KL2541 terminal (MC_PowerStepper): it can be made "
        "to stall (command SimStall) and reports the terminal's status byte/word (NCJOBS DriveStatus); "
        "MC_ReadAxisComponents/MC_ReadParameterSet report the KL2531 encoder and drive types")
    # the simulated drive's mechanics (nc_server/drives/mechanics.py): torque = SimLoadInertia * a +
    # SimViscousFriction * v + SimCoulombFriction * sign(v), shown in % of SimRatedTorque (NCTOPLC SetTorque, ActTorque)
    SimLoadInertia: float = _p(1e-4, "nonneg", "simulated mechanics: load inertia seen by the motor [N*m*s^2/u]")
    SimViscousFriction: float = _p(1e-4, "nonneg", "simulated mechanics: viscous friction [N*m*s/u]")
    SimCoulombFriction: float = _p(0.02, "nonneg", "simulated mechanics: Coulomb (dry) friction [N*m]")
    SimRatedTorque: float = _p(1.0, "pos", "simulated motor: rated torque, 100 % of the torque fields [N*m]")
    Homed: bool = _p(False, "bool", "axis starts referenced (StateDWord.Homed)")
    AxisEnDataPersistence: bool = _p(
        False, "bool", "TwinCAT 'Data persistence' (MC_AxisPara 1037): with [nc] retain_file the NC keeps the "
        "axis's actual position and homed flag across a restart (nc_server/server/retain.py)")
    # loop movement and override type (MC_AxisPara 1033, 1034, 1039; their effect: jobs/position.py). Bad values
    # get TwinCAT's axis errors 0x4323, 0x4328, 0x430D (Axis Errors,
    # https://infosys.beckhoff.com/content/1033/tc3ncerrcode/513133323.html).
    AxisEnLoopingDistance: bool = _p(
        False, "bool", "TwinCAT 'Loop' (MC_AxisPara 1033, ADS axis 0x13, bEnableLoop): loop movement enabled. With a "
        "non-zero AxisLoopingDistance a positioning that ends at rest and would reach its target from the other side "
        "goes on to the loop point (target + AxisLoopingDistance), stops there and returns to the target")
    AxisLoopingDistance: float = _p(
        0.0, "real", "TwinCAT 'Loop distance (+/-)' (MC_AxisPara 1034, ADS axis 0x14, fLoopDistance) [u]: its sign is "
        "the side the target is approached from (> 0: from above, the last leg runs in negative direction), its size the "
        "distance of the loop point beyond the target; 0: no loop")
    AxisOverrideType: float = _p(
        4.0, "int", "TwinCAT 'Velocity Override Type' (MC_AxisPara 1039; Setpoint Generator, "
        "https://infosys.beckhoff.com/content/1033/tc3_system/3396207115.html): 1 reduced (instantaneous), 2 original "
        "(instantaneous), 3 reduced (iterated), 4 original (iterated). Reduced: the override refers to the peak "
        "velocity of the command's profile at 100 %; original: to its commanded velocity. Instantaneous: an override "
        "raise that the new profile cannot reach (its peak stays below the new level) is not applied. Default 4, "
        "how this NC behaved before the parameter acted (TwinCAT's own default seems to be 3)")

    def __post_init__(self) -> None:
        for f in fields(self):
            setattr(self, f.name, _check(f.name, f.metadata["kind"], getattr(self, f.name), f.name))
        if self.AxisEnMinSoftPosLimit and self.AxisEnMaxSoftPosLimit and self.AxisMinSoftPosLimit >= self.AxisMaxSoftPosLimit:
            raise ConfigError("AxisMinSoftPosLimit", "must be below AxisMaxSoftPosLimit", _BAD_VALUE)
        # (the dynamics the planner can handle: the table's ranges of AxisVeloMax/AxisAcc/AxisDec/AxisJerk)

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], where: str = "axis") -> AxisParams:
        """Build from a config table, naming the offending key on error.

        Raises:
            ConfigError: unknown key, wrong type or out-of-range value.
        """
        known = {f.name: f for f in fields(cls)}
        kw: dict[str, Any] = {}
        for k, v in data.items():
            if k in ALIASES:
                k = ALIASES[k]
            if k not in known:
                near = difflib.get_close_matches(str(k), [*known, *ALIASES], n=1)
                raise ConfigError(f"{where}.{k}", "unknown axis parameter" + (f" (did you mean {near[0]}?)" if near else ""),
                                  int(ErrorCodes.ADSERR_DEVICE_INVALIDOFFSET))
            kw[k] = _check(k, known[k].metadata["kind"], v, f"{where}.{k}")
        try:
            return cls(**kw)
        except ConfigError as exc:
            raise exc.renamed(f"{where}.{exc.key}") from None

    def with_value(self, name: str, value: Any) -> AxisParams:
        """A copy with one parameter changed (validated; self stays untouched).

        Raises:
            ConfigError: invalid value.
        """
        return replace(self, **{name: value})

    @staticmethod
    def kind(name: str) -> str:
        return _KINDS[name]


_MASK_MAX = float(2 ** 32 - 1)  # a 32-bit encoder (UDINT)
_BAD_VALUE = int(ErrorCodes.ADSERR_DEVICE_INVALIDPARM)  # 0x70B, as WriteParameter refuses the same value


def _check(name: str, kind: str, value: Any, key: str) -> Any:
    # a bad value gets the parameter's own TwinCAT code where the table gives one (a number for a BOOL
    # counts as a bad value, a non-number for a number as the wrong type: 0x70B)
    bad = _CODES.get(name, _BAD_VALUE)
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(key, f"must be true or false, got {value!r}", bad)
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(key, f"must be a number, got {value!r}", _BAD_VALUE)
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(key, f"must be finite, got {value}", bad)
    if kind == "pos" and value <= 0:
        raise ConfigError(key, f"must be > 0, got {value}", bad)
    if kind == "nonneg" and value < 0:
        raise ConfigError(key, f"must be >= 0, got {value}", bad)
    if kind == "mask" and not (value.is_integer() and 1.0 <= value <= _MASK_MAX and (int(value) & (int(value) + 1)) == 0):
        # an encoder mask is the maximum value of a k-bit counter (Infosys: 'Encoder Mask (maximum encoder value)')
        raise ConfigError(key, f"must be 2^k - 1 for k = 1..32 (a k-bit encoder), got {value:g}", bad)
    if kind == "int" and value != math.floor(value):
        raise ConfigError(key, f"must be a whole number, got {value:g}", bad)
    entry = _RANGES.get(name)
    if entry is not None and not entry.in_range(value):
        raise ConfigError(key, f"must be {entry.range_text()} (MC_AxisPara {entry.number}), got {value:g}", bad)
    return value


_KINDS: dict[str, str] = {f.name: f.metadata["kind"] for f in fields(AxisParams)}

#: TwinCAT names that mean the same stored parameter (config keys; the table maps the numbers).
ALIASES: dict[str, str] = {
    "AxisMaxVelocity": "AxisVeloMax",
    "AxisManualVelocityFast": "AxisVeloManFast",
    "AxisManualVelocitySlow": "AxisVeloManSlow",
}

#: AxisParams field -> the table entry whose range validates it (all entries of one field share the range;
#: the entry of the field's own name is the one an error names: AxisVeloMax is 1003, not PLCopen's 8)
_RANGES: dict[str, ParamEntry] = {}
for _e in PARAMETERS:
    if _e.source == "param" and _e.store is not None and (_e.min is not None or _e.max is not None):
        if _e.store not in _RANGES or _e.name == _e.store:
            _RANGES[_e.store] = _e

#: AxisParams field -> the TwinCAT code of a bad value (the table's ``code``; fields without one: 0x70B)
_CODES: dict[str, int] = {e.store: e.code for e in PARAMETERS if e.source == "param" and e.store and e.code is not None}

#: Read-only status parameters, answered from the live axis state by NcCore.
STATUS_PARAMS = frozenset(e.number for e in PARAMETERS if e.source == "status")


def param_entry(number: int) -> ParamEntry:
    """The table entry of MC_AxisPara ``number``.

    Raises:
        NcError: 0x703 (ADS "invalid index offset") for a number TcMC does not define.
    """
    e = PARAMETERS.by_number(number)
    if e is None:
        raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDOFFSET, f"no MC_AxisPara number {number}")
    return e


def param_name(number: int) -> str:
    """The stored parameter (AxisParams field) a MC_AxisPara number reads/writes.

    Raises:
        NcError: 0x703 for a number that is not a stored parameter (unknown, status or fixed).
    """
    e = param_entry(number)
    if e.store is None:
        raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDOFFSET, f"parameter {number} ({e.name}) is not a stored parameter")
    return e.store


def param_number(name: str) -> int | None:
    """The MC_AxisPara number that writes AxisParams field (or MC_AxisPara name) ``name``: the entry of that
    name, else the Beckhoff entry (the highest number) storing it; None if no writable entry stores it."""
    e = PARAMETERS.by_name(name)
    if e is not None and e.writable:
        return e.number
    cands = [x for x in PARAMETERS.stores().get(ALIASES.get(name, name), []) if x.writable]
    return max(cands, key=lambda x: x.number).number if cands else None


@dataclass
class AxisConfig:
    """One configured axis."""

    AxisId: int
    Name: str = ""
    params: AxisParams = field(default_factory=AxisParams)

    def __post_init__(self) -> None:
        if isinstance(self.AxisId, bool) or not isinstance(self.AxisId, int) or not 1 <= self.AxisId <= 65535:
            raise ConfigError("AxisId", f"must be an integer 1..65535, got {self.AxisId!r}",
                              int(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED))
        if not self.Name:
            self.Name = f"Axis{self.AxisId}"
