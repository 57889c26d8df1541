"""A response body sent as one secure-channel message chunk (OPC 10000-6 §6.7.2), its headers written directly.

asyncua's SecureConnection.message_to_binary builds a MessageChunk per chunk (three header dataclasses),
encodes each header through its generic serializer and asks the policy for its block and signature sizes
several times over: about half of the ~25 us it takes to sign and encrypt a Publish response on a fast host,
50 times a second. `secure_message` writes the message header, the security header (the token id) and the
sequence header with one struct each and leaves padding, signature and encryption to the policy's own
symmetric cryptography, as asyncua does; a body larger than one chunk (or an empty one, of which asyncua
makes no chunk) goes through asyncua. The bytes, and the
channel's sequence numbers, are asyncua's own (tests/unit/opcua/test_secure_send.py compares them under the
None, Sign and SignAndEncrypt modes).

asyncua internals this relies on (the >=2.1,<2.2 pin): SecureConnection's `security_policy`, `security_token`,
`_limits` and `_sequence_number`, and how MessageChunk.max_body_size sizes a chunk.
"""

from __future__ import annotations

import struct
from typing import Any

from asyncua import ua

_HEADER = struct.Struct("<3ssII").pack  # MessageType, IsFinal, MessageSize, SecureChannelId
_TOKEN = struct.Struct("<I").pack  # the symmetric security header: TokenId
_SEQUENCE = struct.Struct("<II").pack  # SequenceNumber, RequestId
_SEQUENCE_SIZE = 8
_HEADERS_SIZE = 12 + 4  # message header with the channel id, security header
_MESSAGE, _SINGLE = ua.MessageType.SecureMessage, ua.ChunkType.Single


def secure_message(connection: Any, body: bytes, request_id: int) -> bytes:
    """`connection.message_to_binary(body, SecureMessage, request_id)`: the channel's next sequence number."""
    crypto = connection.security_policy.symmetric_cryptography
    block, encrypted_block, signature_size = (
        crypto.plain_block_size(), crypto.encrypted_block_size(), crypto.signature_size())
    # MessageChunk.max_body_size: the largest body one chunk of the peer's receive buffer holds
    largest = ((connection._limits.max_send_buffer - _HEADERS_SIZE) // encrypted_block * block
               - _SEQUENCE_SIZE - signature_size - crypto.min_padding_size())
    if not body or len(body) > largest:
        return bytes(connection.message_to_binary(body, message_type=_MESSAGE, request_id=request_id))
    sequence = connection._sequence_number + 1
    if sequence >= 1 << 32:
        sequence = 1
    connection._sequence_number = sequence
    token = connection.security_token
    plain = _SEQUENCE(sequence, request_id) + body
    plain += crypto.padding(len(plain))
    signed_size = len(plain) + signature_size
    if signed_size % block:
        raise ua.UaError("Encryption error")  # as asyncua's MessageChunk.encrypted_size
    security = _TOKEN(token.TokenId)
    header = _HEADER(_MESSAGE, _SINGLE, _HEADERS_SIZE + signed_size // block * encrypted_block, token.ChannelId)
    return header + security + crypto.encrypt(plain + crypto.signature(header + security + plain))
