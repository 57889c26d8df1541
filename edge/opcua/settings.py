"""The OPC UA server's settings as the service layer hands them over (secrets already read).

Pure (no asyncua): the config section builds it, check-config inspects it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

# Config names of the endpoint security modes -> asyncua SecurityPolicyType member names.
SECURITY_MODES: dict[str, str] = {
    "Basic256Sha256-SignAndEncrypt": "Basic256Sha256_SignAndEncrypt",
    "Basic256Sha256-Sign": "Basic256Sha256_Sign",
    "None": "NoSecurity",
}
DEFAULT_SECURITY = ("Basic256Sha256-SignAndEncrypt",)


@dataclass(frozen=True)
class OpcUaSettings:
    state_dir: Path
    host: str = "0.0.0.0"
    port: int = 4840
    path: str = "/focas-edge"
    security: tuple[str, ...] = DEFAULT_SECURITY
    allow_anonymous: bool = False
    users: Mapping[str, str] = field(default_factory=dict, repr=False)  # user name -> password
    certificate_file: Path | None = None  # DER or PEM; generated into state_dir when not given
    private_key_file: Path | None = None
    application_uri: str = "urn:focas-edge:gateway"
    namespace_uri: str = "urn:focas-edge:machines"
    server_name: str = "focas-edge"
    threaded: bool = False  # True: its own thread and event loop (docs/opcua.md has the measurement)
    write_timeout_s: float = 30.0
    max_sessions: int = 20  # open client connections at once

    @property
    def endpoint(self) -> str:
        host = "[::]" if self.host == "::" else self.host
        return f"opc.tcp://{host}:{self.port}{self.path}"

    @property
    def encrypted(self) -> bool:
        return any(mode != "None" for mode in self.security)
