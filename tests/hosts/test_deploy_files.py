"""Fast checks of deploy/ and of the host tests' own logic (no Docker, no namespaces)."""
from __future__ import annotations

import subprocess
import tomllib

import pytest

from znc_testing.hostlib import ROOT, AxisSample, Event, compose_command, motion_on_its_own, parse_events


def test_pyproject_lists_every_package() -> None:
    """The wheel (the images install it) must hold every package of the tree."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    tops = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests", "bench"}
    found = {p.parent.relative_to(ROOT).as_posix().replace("/", ".") for top in tops
             for p in (ROOT / top).rglob("__init__.py") if "__pycache__" not in p.parts}
    assert found <= listed, f"not in [tool.setuptools] packages: {sorted(found - listed)}"


def test_compose_file_is_valid_for_the_installed_compose() -> None:
    cmd = compose_command()
    if cmd is None:
        pytest.skip("no compose tool (docker-compose or docker compose)")
    r = subprocess.run([*cmd, "-f", str(ROOT / "deploy" / "compose.yaml"), "config", "-q"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr


def test_standby_compose_files_are_valid_together() -> None:
    """deploy/compose.standby.yaml over compose.yaml and compose.drives.yaml: both nodes of nc1 read the pair's TOML,
    both start as standby (a restarted container must not start active), and the drive host's timeout default is longer than the takeover bound."""
    cmd = compose_command()
    if cmd is None:
        pytest.skip("no compose tool (docker-compose or docker compose)")
    files = [a for f in ("compose.yaml", "compose.drives.yaml", "compose.standby.yaml")
             for a in ("-f", str(ROOT / "deploy" / f))]
    r = subprocess.run([*cmd, *files, "config"], capture_output=True, text=True, timeout=300,
                       env={"PATH": "/usr/bin:/bin:/usr/local/bin", "ZNC_BUILD": "/nonexistent"})
    assert r.returncode == 0, r.stderr
    for needle in ("redundancy.node=a", "redundancy.node=b", "redundancy.start=standby",
                   "standby/nc1.toml:/etc/zenoh-nc/nc1.toml:ro"):
        assert needle in r.stdout, needle
    from nc_server.drives.remote.config import takeover_bound
    from nc_server.server.config import load_config

    cfg = load_config(ROOT / "deploy" / "standby" / "nc1.toml")
    assert cfg.redundancy.enabled and cfg.name == "nc1"
    assert takeover_bound(cfg.redundancy.takeover_cycles, cfg.cycle_time) < 1.0  # ZNC_DRIVE_TIMEOUT_S default 1 s


def test_scripts_parse() -> None:
    for sh in ("deploy/images/build.sh", "deploy/deploy.sh"):
        r = subprocess.run(["bash", "-n", str(ROOT / sh)], capture_output=True, text=True, timeout=30)
        assert r.returncode == 0, f"{sh}: {r.stderr}"
    r = subprocess.run(["sh", "-n", str(ROOT / "deploy/images/znc-run")], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr


def test_event_lines_parse_with_and_without_compose_prefixes() -> None:
    text = ("plc1 1700000000.250 nc1:1 move -> 100.000\n"
            "plc1_1    | plc1 1700000001.500 nc2:1 error 0x4B0F (MC_MoveAbsolute); reset in 2 s\n"
            "plc-run: WARNING something else\n")
    ev = parse_events(text)
    assert [(e.client, e.nc, e.axis, e.text[:8]) for e in ev] == [("plc1", "nc1", 1, "move -> "),
                                                                   ("plc1", "nc2", 1, "error 0x")]


def _s(t: float, v: float) -> AxisSample:
    return AxisSample(t, "nc1", int(t * 1000), 1, 1 << 20, 0, 0.0, v)


def test_motion_on_its_own_allows_a_stop_ramp_and_commanded_moves() -> None:
    samples = [_s(10.0, 50.0), _s(10.1, 20.0), _s(10.2, 0.0), _s(10.3, 0.0), _s(11.0, 30.0)]
    cmd = [Event("plc1", 10.9, "nc1", 1, "move -> 100.000")]
    assert motion_on_its_own(samples, cmd, t0=10.05) is None


def test_motion_on_its_own_finds_a_restart_without_a_command() -> None:
    samples = [_s(10.0, 50.0), _s(10.2, 0.0), _s(11.0, 30.0)]
    old = [Event("plc1", 9.0, "nc1", 1, "move -> 100.000"), Event("plc2", 10.9, "nc1", 2, "move -> 1.0")]
    v = motion_on_its_own(samples, old, t0=10.05)
    assert v is not None and "without a command" in v


def test_motion_on_its_own_accepts_a_command_sent_during_the_standstill_before_the_cut() -> None:
    samples = [_s(9.0, 40.0), _s(9.5, 0.0), _s(10.2, 0.0), _s(10.4, -99.0)]
    other_client = [Event("plc2", 9.9, "nc1", 1, "move -> 25.000")]
    assert motion_on_its_own(samples, other_client, t0=10.0) is None


def test_each_container_mounts_only_its_own_key_and_certificate() -> None:
    """deploy/compose.yaml: every service mounts ca.pem and its own <id>.pem/.key (never the whole
    certs directory, the CA key or another identity's key); only the router the roles file, only nc-opcua
    its users file and OPC UA application certificate, only nc-web its users file and cookie secret."""
    import re

    text = (ROOT / "deploy" / "compose.yaml").read_text()
    services = text.split("\nservices:\n", 1)[1].split("\nnetworks:\n", 1)[0]
    blocks = re.split(r"\n  (?=[a-z0-9]+:\n)", "\n" + services)
    seen = set()
    for block in blocks:
        m = re.match(r"([a-z0-9]+):\n", block.strip("\n") + "\n")
        if not m:
            continue
        sid = m.group(1)
        seen.add(sid)
        mounts = re.findall(r"^\s+- \$\{ZNC_BUILD:-\./\.build\}/(\S+):(\S+):ro$", block, re.M)
        sources = sorted(src for src, _ in mounts)
        want = sorted(["certs/ca.pem", f"certs/{sid}.pem", f"certs/{sid}.key"]
                      + (["etc/roles.toml"] if sid == "router" else [])
                      + (["opcua/opcua.der", "opcua/opcua.key.pem", "opcua/users.toml"] if sid == "opcua" else [])
                      + (["web/secret", "web/users.toml"] if sid == "web" else []))
        assert sources == want, (sid, sources)
    assert seen == {"router", "nc1", "nc2", "plc1", "plc2", "opcua", "web"}
    assert re.search(r"\.build\}/certs:", text) is None  # no directory mount left (anchor included)
