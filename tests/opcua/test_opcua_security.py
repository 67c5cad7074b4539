"""nc-opcua with Basic256Sha256 (SignAndEncrypt) and generated application certificates; the users file and
the certificate tool on their own; the CLI's refusals of bad options (exit 2 with a message)."""
from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path
from typing import Iterator

import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography import x509

from nc_opcua.certs import application_uri_of, make_app_certificate
from nc_link.users import UsersError, add_user, hash_password, load_users, verify_password
from znc_testing import NcServerProcess
from znc_testing.opcua_testing import NcOpcuaProcess, call, client, opcua_command, served, start_nc_opcua, value

SERVER_URI = "urn:zenoh-nc:nc-opcua:test"
CLIENT_URI = "urn:zenoh-nc:test-client"
STRANGER_URI = "urn:zenoh-nc:test-stranger"


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("pki")
    make_app_certificate(d, "server", SERVER_URI)
    make_app_certificate(d, "client", CLIENT_URI)
    return d


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory, nc: NcServerProcess, users_file: Path,
           certs: Path) -> Iterator[NcOpcuaProcess]:
    p = start_nc_opcua(tmp_path_factory.mktemp("opcua-sec"), nc.endpoint,
                       ["--users", str(users_file), "--cert", str(certs / "server.der"),
                        "--key", str(certs / "server.key.pem"), "--security", "encrypt"])
    try:
        yield p
    finally:
        p.stop()


@pytest.fixture(scope="module")
def trusting(tmp_path_factory: pytest.TempPathFactory, nc: NcServerProcess, users_file: Path,
             certs: Path) -> Iterator[NcOpcuaProcess]:
    trust = tmp_path_factory.mktemp("trust")
    (trust / "client.der").write_bytes((certs / "client.der").read_bytes())
    make_app_certificate(certs, "stranger", STRANGER_URI)  # a valid certificate nobody put in the trust directory
    p = start_nc_opcua(tmp_path_factory.mktemp("opcua-trust"), nc.endpoint,
                       ["--users", str(users_file), "--cert", str(certs / "server.der"),
                        "--key", str(certs / "server.key.pem"), "--security", "sign", "--trust", str(trust)])
    try:
        yield p
    finally:
        p.stop()


async def _secure_client(url: str, certs: Path, name: str, uri: str, mode: ua.MessageSecurityMode) -> Client:
    c = client(url, "bob", "bob-pw")
    c.application_uri = uri
    await c.set_security(SecurityPolicyBasic256Sha256, str(certs / f"{name}.der"), str(certs / f"{name}.key.pem"),
                         server_certificate=str(certs / "server.der"), mode=mode)
    return c


def test_trust_directory_admits_only_its_certificates(trusting: NcOpcuaProcess, certs: Path) -> None:
    async def body() -> None:
        c = await _secure_client(trusting.url, certs, "client", CLIENT_URI, ua.MessageSecurityMode.Sign)
        async with c:
            await served(c, "nc1.1.ActPos")
            assert isinstance(await value(c, "nc1.1.ActPos"), float)
        stranger = await _secure_client(trusting.url, certs, "stranger", STRANGER_URI, ua.MessageSecurityMode.Sign)
        with pytest.raises(ua.UaStatusCodeError) as err:
            async with stranger:
                await value(stranger, "nc1.1.ActPos")
        assert err.value.code == ua.StatusCodes.BadCertificateUntrusted
    asyncio.run(asyncio.wait_for(body(), 240))
    assert "is not in the trust directory" in trusting.stderr()


def test_certificate_carries_the_application_uri(certs: Path) -> None:
    assert application_uri_of(certs / "server.der") == SERVER_URI
    cert = x509.load_der_x509_certificate((certs / "server.der").read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "localhost" in san.get_values_for_type(x509.DNSName)
    ku = cert.extensions.get_extension_for_class(x509.KeyUsage).value
    assert ku.digital_signature and ku.key_encipherment and ku.data_encipherment and ku.content_commitment
    assert (certs / "server.key.pem").stat().st_mode & 0o077 == 0


def test_sign_and_encrypt_with_a_user(secure: NcOpcuaProcess, certs: Path) -> None:
    async def body() -> None:
        c = client(secure.url, "alice", "alice-pw")
        c.application_uri = CLIENT_URI
        await c.set_security(SecurityPolicyBasic256Sha256, str(certs / "client.der"), str(certs / "client.key.pem"),
                             server_certificate=str(certs / "server.der"),
                             mode=ua.MessageSecurityMode.SignAndEncrypt)
        async with c:
            await served(c, "nc1.1.ActPos")
            assert isinstance(await value(c, "nc1.1.ActPos"), float)
            assert (await call(c, "nc1.1", "Reset"))[0] == 0
        plain = client(secure.url, "alice", "alice-pw")  # no security: the endpoint does not offer it
        with pytest.raises(Exception):
            async with plain:
                await value(plain, "nc1.1.ActPos")
    asyncio.run(asyncio.wait_for(body(), 240))


def test_users_file(tmp_path: Path) -> None:
    stored = hash_password("pw")
    assert stored.startswith("scrypt$") and verify_password("pw", stored) and not verify_password("px", stored)
    assert not verify_password("pw", "scrypt$broken")
    f = tmp_path / "u.toml"
    add_user(f, "op1", "operator", "secret")
    add_user(f, "op1", "engineer", "secret2")  # replaced
    users = load_users(f)
    assert users["op1"].role == "engineer" and verify_password("secret2", users["op1"].password_hash)
    assert f.stat().st_mode & 0o077 == 0
    f.write_text('[user.x]\nrole = "admin"\npassword = "scrypt$1$1$1$a$b"\n')
    with pytest.raises(UsersError, match=r"user\.x\.role: must be one of observer, operator, engineer"):
        load_users(f)
    f.write_text('[user.x]\nrole = "operator"\npassword = "plain"\n')
    with pytest.raises(UsersError, match=r"user\.x\.password"):
        load_users(f)


@pytest.mark.parametrize("args, message", [
    (["--connect", "tcp/127.0.0.1:1"], "no users"),
    (["--connect", "tcp/127.0.0.1:1", "--anonymous", "--cert", "x.der"], "--cert and --key go together"),
    (["--connect", "tcp/127.0.0.1:1", "--users", "/nonexistent/users.toml"], "cannot read the users file"),
])
def test_cli_refuses_bad_options(args: list[str], message: str) -> None:
    out = subprocess.run([*opcua_command(), *args], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and message in out.stderr, out.stderr


def test_cli_refuses_a_certificate_of_another_uri(certs: Path) -> None:
    out = subprocess.run([*opcua_command(), "--connect", "tcp/127.0.0.1:1", "--anonymous",
                          "--cert", str(certs / "server.der"), "--key", str(certs / "server.key.pem"),
                          "--app-uri", "urn:other"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and "differs from the certificate's" in out.stderr, out.stderr


def test_user_subcommand_reads_the_password_from_stdin(tmp_path: Path) -> None:
    f = tmp_path / "users.toml"
    out = subprocess.run([*opcua_command(), "user", str(f), "carol", "--role", "observer"], input="pw-carol\n",
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert verify_password("pw-carol", load_users(f)["carol"].password_hash)
    assert sys.executable  # (the same interpreter runs the subcommand)
