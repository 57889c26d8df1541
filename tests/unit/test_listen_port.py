"""The relay's port lies below the ephemeral range, so nothing else is given it while the relay is closed."""

import socket

from tests.helpers import _ephemeral_low, free_listen_port


def test_listen_port_is_below_the_ephemeral_range_and_binds_again() -> None:
    port = free_listen_port()
    assert 20000 <= port < _ephemeral_low()
    for _ in range(2):  # listen, close, listen again on the same port
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("127.0.0.1", port))
            s.listen()
