"""The command registry equals the wire contract (issue 16, boundary 3): every command of
schema/protocol.json is registered exactly once, by the NC core or by the server's request handler,
nothing else is registered, and what each registration is agrees with the contract's properties."""
from __future__ import annotations

import pytest

import nc_server.server.handler as handler  # (imports the core too: both layers' registrations)
from nc_schema import COMMAND_SPECS, COMMANDS, MOTION_COMMANDS, ErrorCodes
from nc_server.core import KINDS
from nc_server.core.commands import CORE_HANDLERS, REGISTRY, CommandRegistry, RegistryError
from znc_testing.nc_core import cmd, powered

#: what the core's separate tables held before the registry (nc.py AMENDMENTS and _ADMIN, jobs KINDS)
OLD_KINDS = {"MoveAbsolute", "MoveRelative", "MoveAdditive", "MoveModulo", "MoveContinuousAbsolute",
             "MoveContinuousRelative", "MoveAbsoluteOrRestart", "MoveVelocity", "Jog", "Stop", "Halt", "OrientedStop",
             "Home", "GearIn", "GearInFloat", "GearInDyn", "ExtSetPointGenEnable"}
OLD_AMENDMENTS = {"NewPos", "NewPosAndVelo", "ChangeDynParam"}
OLD_ADMIN = {"ReadParameterSet", "ReadAxisComponents", "SetExternalError", "SimStall", "SimTerminalError", "Reset",
             "StopRelease", "SetOverride", "ReadParameter", "WriteParameter", "SetActualPosition",
             "SetActualPositionOnTheFly", "SetReferenceFlag", "GearOut", "GearOutExt", "ExtSetPointGenDisable",
             "MoveSuperImposed", "AbortSuperposition", "TouchProbe", "AbortTrigger", "SimProbeSignal"}
#: the server handler's own commands before (its _execute's special cases)
OLD_SERVER = {"Info", "Claim", "Release", "HandOver"}


def test_every_contract_command_is_registered_and_nothing_else() -> None:
    assert REGISTRY.unregistered() == []
    assert list(REGISTRY) and set(REGISTRY) == set(COMMAND_SPECS) == set(COMMANDS)


def test_each_registration_agrees_with_the_contract() -> None:
    for name, reg in REGISTRY.items():
        spec = COMMAND_SPECS[name]
        assert reg.spec is spec, name
        assert reg.layer == spec.layer, name
        assert (reg.how == "amendment") == spec.amends, name
        assert reg.motion == spec.motion == (name in MOTION_COMMANDS), name
        assert spec.cls == COMMANDS[name]["class"] and spec.scope == COMMANDS[name].get("scope", "axis"), name
        if reg.how == "job":
            assert reg.kind is not None and name in reg.kind.commands and reg.kind.motion == spec.motion, name
        else:
            assert reg.kind is None, name


def test_the_layers_dispatch_exactly_their_registrations() -> None:
    core = {n for n, r in REGISTRY.items() if r.layer == "core"}
    assert set(CORE_HANDLERS) == core
    assert set(handler._OWN) == {n for n, r in REGISTRY.items() if r.layer == "server"} == OLD_SERVER
    assert REGISTRY.guards == {"SetOverride": ("server",)} and set(handler._GUARDS) == {"SetOverride"}
    # the tables the registry replaced: the same commands, the same way
    assert KINDS == REGISTRY.kinds() and set(KINDS) == OLD_KINDS
    assert {n for n, r in REGISTRY.items() if r.how == "amendment"} == OLD_AMENDMENTS
    assert {n for n, r in REGISTRY.items() if r.how == "function" and r.layer == "core"} == OLD_ADMIN
    assert core == OLD_KINDS | OLD_AMENDMENTS | OLD_ADMIN


def test_refused_after_stall_is_what_it_was() -> None:
    assert handler.REFUSED_AFTER_STALL == (MOTION_COMMANDS | OLD_AMENDMENTS) - {"Stop", "Halt"}


def test_the_core_alone_does_not_run_a_server_command() -> None:
    core = powered(1)
    for name in sorted(OLD_SERVER - {"Info"}):
        args = {"To": "other"} if name == "HandOver" else {}
        assert cmd(core, name, **args)["error"] == ErrorCodes.ADSERR_DEVICE_SRVNOTSUPP


def test_a_registration_against_the_contract_is_refused() -> None:
    reg = CommandRegistry(COMMAND_SPECS)
    reg.register("Reset", where="test")
    with pytest.raises(RegistryError, match="twice"):
        reg.register("Reset", where="again")
    with pytest.raises(RegistryError, match="not a command of the contract"):
        reg.register("NoSuchCommand", where="test")
    with pytest.raises(RegistryError, match="amends"):
        reg.register("NewPos", where="test")  # an amendment, registered as a function
    with pytest.raises(RegistryError, match="layer"):
        reg.register("Claim", where="test")  # the server's
    with pytest.raises(RegistryError, match="motion"):
        reg.register("GearOut", where="test")  # a motion command registered without motion
    with pytest.raises(RegistryError, match="kind"):
        reg.register("Halt", where="test", how="job", motion=True)  # a job without its kind
    with pytest.raises(RegistryError, match="guard"):
        reg.guard("Reset", layer="core", where="test")
    assert list(reg) == ["Reset"] and len(reg.unregistered()) == len(COMMAND_SPECS) - 1
