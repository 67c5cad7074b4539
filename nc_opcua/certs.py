"""OPC UA application instance certificates (``nc-opcua cert DIR --uri URI``).

OPC UA Part 6 (6.2.2) wants the application instance certificate of a server or client to carry its
ApplicationUri as a URI in subjectAltName (plus the host names / addresses it is reached at), key usages
digitalSignature, nonRepudiation, keyEncipherment, dataEncipherment, and an RSA key (Basic256Sha256: 2048 to
4096 bits, SHA-256 signature). zenoh's certificates (deploy/certs/make-certs.sh: EC P-256, a private CA) cannot
serve Basic256Sha256, hence this separate tool.

Decisions: self-signed (OPC UA trusts application certificates one by one: a client adds the server's to its
trust list and vice versa; no CA is needed), RSA 2048, SHA-256, valid 5 years, EKU serverAuth and clientAuth
(one tool for the server and its clients), the certificate in DER (``<name>.der``, what OPC UA exchanges) and
the key in PEM (``<name>.key.pem``, mode 0600). Existing files are kept (delete them to renew).

May import: ``cryptography`` and the standard library.
"""
from __future__ import annotations

import datetime as _dt
import ipaddress
import os
from pathlib import Path
from typing import Sequence

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

__all__ = ["make_app_certificate", "application_uri_of"]


def make_app_certificate(out_dir: str | Path, name: str, app_uri: str, hosts: Sequence[str] = ("localhost", "127.0.0.1"),
                         days: int = 5 * 365) -> tuple[Path, Path]:
    """Make ``<out_dir>/<name>.der`` and ``<out_dir>/<name>.key.pem`` (kept if they exist).

    Args:
        name: the certificate's common name and file name.
        app_uri: the ApplicationUri (subjectAltName URI), e.g. ``urn:zenoh-nc:nc-opcua:host1``.
        hosts: DNS names and IP addresses (subjectAltName) the application is reached at.

    Raises:
        ValueError: an empty ``app_uri``.
    """
    if not app_uri:
        raise ValueError("an application certificate needs its ApplicationUri")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cert_path, key_path = out / f"{name}.der", out / f"{name}.key.pem"
    if cert_path.exists() and key_path.exists():
        return cert_path, key_path
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name),
                         x509.NameAttribute(NameOID.ORGANIZATION_NAME, "zenoh-nc")])
    alt: list[x509.GeneralName] = [x509.UniformResourceIdentifier(app_uri)]
    for h in hosts:
        try:
            alt.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            alt.append(x509.DNSName(h))
    now = _dt.datetime.now(_dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - _dt.timedelta(minutes=5))
            .not_valid_after(now + _dt.timedelta(days=days))
            .add_extension(x509.SubjectAlternativeName(alt), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=True, key_encipherment=True,
                                         data_encipherment=True, key_agreement=False, key_cert_sign=False,
                                         crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.TraditionalOpenSSL,
                                  serialization.NoEncryption()))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    return cert_path, key_path


def application_uri_of(cert_path: str | Path) -> str | None:
    """The ApplicationUri (first subjectAltName URI) of a DER or PEM certificate, None if it has none."""
    data = Path(cert_path).read_bytes()
    cert = x509.load_pem_x509_certificate(data) if data.startswith(b"-----") else x509.load_der_x509_certificate(data)
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None
