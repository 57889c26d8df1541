"""Who may connect: the server's application certificate and the user/password check.

The certificate (and its private key) is generated on first start into `<state_dir>/opcua/` unless the
config names files; it is kept across restarts, so a client that trusted it once keeps trusting it.
It is valid for ten years: a gateway that silently renews its certificate every year would break every
client's trust once a year. Passwords are compared in constant time; anonymous sessions are refused
unless the config allows them.
"""

from __future__ import annotations

import hmac
import logging
import os
import socket
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua.crypto import cert_gen
from asyncua.crypto.permission_rules import User, UserRole
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import ExtendedKeyUsageOID

from edge.statefile import write_atomically

log = logging.getLogger(__name__)

CERTIFICATE_DAYS = 3650


@dataclass(frozen=True)
class CertificateFiles:
    certificate: Path  # DER
    private_key: Path  # PEM


def ensure_certificate(directory: Path, application_uri: str, host_name: str | None = None) -> CertificateFiles:
    """The generated certificate in `directory` (made on first call: RSA 2048, SHA-256, the application URI
    and host name as subject alternative names, as OPC 10000-6 §6.2.2 asks)."""
    files = CertificateFiles(directory / "server-cert.der", directory / "server-key.pem")
    if files.certificate.is_file() and files.private_key.is_file():
        return files
    host = host_name or socket.gethostname()
    key = cert_gen.generate_private_key()
    certificate = cert_gen.generate_self_signed_app_certificate(
        key, application_uri, {"organizationName": "focas-edge"},
        [x509.UniformResourceIdentifier(application_uri), x509.DNSName(host)],
        extended=[ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH], days=CERTIFICATE_DAYS)
    directory.mkdir(parents=True, exist_ok=True)
    write_atomically(files.private_key, cert_gen.dump_private_key_as_pem(key))
    os.chmod(files.private_key, 0o600)
    write_atomically(files.certificate, certificate.public_bytes(Encoding.DER))
    log.info("OPC UA certificate generated path=%s application_uri=%s host=%s", files.certificate,
             application_uri, host)
    return files


class PasswordUsers:
    """asyncua's UserManager: a configured user name with its password, or anonymous where allowed."""

    def __init__(self, users: Mapping[str, str], allow_anonymous: bool) -> None:
        self._users = {name: password.encode() for name, password in users.items()}
        self.allow_anonymous = allow_anonymous
        self.refused = 0

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> User | None:
        if username is None:
            if self.allow_anonymous:
                return User(role=UserRole.User, name=None)
            self.refused += 1
            log.warning("OPC UA session refused: anonymous access is off")
            return None
        expected = self._users.get(username)
        given = (password or "").encode()
        # compare against something even for an unknown name, so the time does not tell which names exist
        if not hmac.compare_digest(given, expected if expected is not None else b"\0" * max(len(given), 1)) \
                or expected is None:
            self.refused += 1
            log.warning("OPC UA session refused: wrong user name or password user=%s", username)
            return None
        return User(role=UserRole.User, name=username)
