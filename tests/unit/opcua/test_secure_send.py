"""secure_message's chunk is byte for byte asyncua's SecureConnection.message_to_binary, sequence numbers too."""

from __future__ import annotations

import datetime
import os
from typing import Any

import pytest
from asyncua import ua
from asyncua.common.connection import MessageChunk, SecureConnection, TransportLimits
from asyncua.crypto.security_policies import (
    SecurityPolicyAes128Sha256RsaOaep,
    SecurityPolicyBasic256Sha256,
    SecurityPolicyNone,
)
from cryptography import x509
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import NameOID

from edge.opcua.secure_send import secure_message

_NAME = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "test")])


@pytest.fixture(scope="module")
def certificates() -> tuple[Any, Any, Any]:
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    cert = (x509.CertificateBuilder().subject_name(_NAME).issuer_name(_NAME).public_key(key.public_key())
            .serial_number(1).not_valid_before(datetime.datetime(2020, 1, 1))
            .not_valid_after(datetime.datetime(2040, 1, 1)).sign(key, hashes.SHA256()))
    peer_key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    peer = (x509.CertificateBuilder().subject_name(_NAME).issuer_name(_NAME).public_key(peer_key.public_key())
            .serial_number(2).not_valid_before(datetime.datetime(2020, 1, 1))
            .not_valid_after(datetime.datetime(2040, 1, 1)).sign(peer_key, hashes.SHA256()))
    return cert, key, peer


def _pair(certificates: tuple[Any, Any, Any], policy: type | None,
          mode: ua.MessageSecurityMode) -> tuple[SecureConnection, SecureConnection]:
    """Two connections in the same state: one sends with asyncua, the other with secure_message."""
    secret, seed = os.urandom(32), os.urandom(32)
    connections = []
    for _ in range(2):
        if policy is None:
            security = SecurityPolicyNone()
        else:
            cert, key, peer = certificates
            security = policy(peer, cert, key, mode)
            security.make_local_symmetric_key(secret, seed)
        connection = SecureConnection(security, TransportLimits(max_send_buffer=8192))
        connection.security_token.ChannelId, connection.security_token.TokenId = 17, 3
        connection._sequence_number = 2**32 - 3  # wraps to 1 within the test
        connections.append(connection)
    return connections[0], connections[1]


POLICIES = [(None, ua.MessageSecurityMode.None_),
            (SecurityPolicyBasic256Sha256, ua.MessageSecurityMode.Sign),
            (SecurityPolicyBasic256Sha256, ua.MessageSecurityMode.SignAndEncrypt),
            (SecurityPolicyAes128Sha256RsaOaep, ua.MessageSecurityMode.SignAndEncrypt)]


@pytest.mark.parametrize(("policy", "mode"), POLICIES, ids=lambda p: getattr(p, "__name__", str(p)))
def test_message_is_asyncuas(certificates: tuple[Any, Any, Any], policy: type | None,
                             mode: ua.MessageSecurityMode) -> None:
    theirs, ours = _pair(certificates, policy, mode)
    largest = MessageChunk.max_body_size(theirs.security_policy.symmetric_cryptography, 8192)
    for request_id, size in enumerate([0, 1, 15, 16, 17, 100, 3000, largest - 1, largest, largest + 1, 20_000, 5]):
        body = os.urandom(size)
        expected = theirs.message_to_binary(body, message_type=ua.MessageType.SecureMessage, request_id=request_id)
        assert secure_message(ours, body, request_id) == expected
        assert ours._sequence_number == theirs._sequence_number
