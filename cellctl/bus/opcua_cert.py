"""The gateway's OPC UA application certificate (Basic256Sha256 needs RSA), written by ``cellctl secure init``.

OPC 10000-6 6.2.2 wants the ApplicationUri in the certificate's subjectAltName; asyncua's generator
follows that profile (key usages for signing and encryption, server and client auth).
"""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path

__all__ = ["OPCUA_DIR", "write_server_certificate"]

APPLICATION_URI = "urn:cellctl:gateway:opcua"
"""The OPC UA gateway's application URI: the certificate carries it and the server announces it."""

OPCUA_DIR = "opcua"
"""Folder of a ``cellctl secure init`` deployment that holds ``server.pem`` and ``server.key``."""


def write_server_certificate(folder: Path, host: str, days: int = 825) -> list[Path]:
    """Write ``server.pem`` (self-signed, PEM) and ``server.key`` (PKCS#8 PEM, mode 0600) into ``folder``.

    Args:
        host: the address PLCs connect to (an IP or a DNS name), put in the subjectAltName beside the URI.
    """
    from asyncua.crypto import cert_gen
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization
    from cryptography.x509.oid import ExtendedKeyUsageOID


    folder.mkdir(parents=True, exist_ok=True)
    os.chmod(folder, 0o700)
    key = cert_gen.generate_private_key()
    try:
        alt: x509.GeneralName = x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        alt = x509.DNSName(host)
    cert = cert_gen.generate_self_signed_app_certificate(
        key,
        "cellctl OPC UA gateway",
        {"organizationName": "cellctl"},
        [x509.UniformResourceIdentifier(APPLICATION_URI), alt],
        extended=[ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
        days=days,
    )
    key_path, cert_path = folder / "server.key", folder / "server.pem"
    for p in (key_path, cert_path):
        p.unlink(missing_ok=True)
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(cert_gen.dump_private_key_as_pem(key))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    os.chmod(cert_path, 0o644)
    return [cert_path, key_path]
