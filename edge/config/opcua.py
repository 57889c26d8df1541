"""The `opcua:` section: the optional OPC UA server (docs/opcua.md), off by default.

    opcua:
      enabled: true
      port: 4840
      users:
        - {username: scada, password_file: /run/credentials/focas-edge.service/opcua-scada}
        - {username: mes, password_env: FOCAS_EDGE_OPCUA_MES}

Like MQTT's, a user's password never lives in the file: an environment variable or a file (a systemd
credential). Anonymous sessions and the unencrypted `None` endpoint are each off unless asked for, and
check-config warns when they are on. The section is validated whether or not asyncua is installed;
`missing_extra` (edge.opcua) says when `enabled` cannot run.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from edge import ConfigError
from edge.config.fields import HostName, _Model, check_file

# The endpoint security modes (edge.opcua.settings.SECURITY_MODES maps them to asyncua's policies).
SecurityMode = Literal["Basic256Sha256-SignAndEncrypt", "Basic256Sha256-Sign", "None"]
DEFAULT_SECURITY: tuple[SecurityMode, ...] = ("Basic256Sha256-SignAndEncrypt",)


class OpcUaUser(_Model):
    username: str = Field(min_length=1, max_length=128)
    password: object = Field(default=None, exclude=True, repr=False)
    password_env: str | None = None
    password_file: Path | None = None

    @field_validator("password")
    @classmethod
    def _no_literal_password(cls, value: object) -> None:
        if value is not None:
            raise ValueError("secrets do not belong in the config file; use password_env: VARIABLE or "
                             "password_file: /run/credentials/... (a systemd credential)")
        return None

    @model_validator(mode="after")
    def _one_source(self) -> OpcUaUser:
        if (self.password_env is None) == (self.password_file is None):
            raise ValueError(f"user {self.username!r}: give exactly one of password_env, password_file")
        return self


class OpcUaConfig(_Model):
    enabled: bool = False
    host: HostName = "0.0.0.0"
    port: int = Field(default=4840, ge=1, le=65535)
    path: str = "/focas-edge"
    security: list[SecurityMode] = Field(default_factory=lambda: list(DEFAULT_SECURITY), min_length=1)
    allow_anonymous: bool = False
    users: list[OpcUaUser] = Field(default_factory=list)
    certificate_file: Path | None = None  # DER or PEM; else generated into <state_dir>/opcua on first start
    private_key_file: Path | None = None
    threaded: bool = False  # the server in the daemon's event loop (the measured default, docs/opcua.md)
    write_timeout_s: float = Field(default=30.0, gt=0, le=600)
    max_sessions: int = Field(default=20, ge=1, le=1000)

    @field_validator("path")
    @classmethod
    def _endpoint_path(cls, value: str) -> str:
        if not value.startswith("/") or any(c.isspace() for c in value):
            raise ValueError(f"{value!r}: expected an endpoint path like /focas-edge")
        return value

    @field_validator("security")
    @classmethod
    def _unique(cls, value: list[str]) -> list[str]:
        if len(set(value)) != len(value):
            raise ValueError(f"{value}: a mode is listed twice")
        return value

    @field_validator("certificate_file", "private_key_file")
    @classmethod
    def _readable(cls, value: Path | None) -> Path | None:
        return check_file(value)

    @model_validator(mode="after")
    def _usable(self) -> OpcUaConfig:
        if (self.certificate_file is None) != (self.private_key_file is None):
            raise ValueError("give certificate_file and private_key_file together (or neither: one is generated)")
        names = [user.username for user in self.users]
        if len(set(names)) != len(names):
            raise ValueError(f"users: a username is listed twice ({names})")
        if self.enabled and not self.users and not self.allow_anonymous:
            raise ValueError("enabled with no users and allow_anonymous false: nobody could connect; add users "
                             "(username + password_file/password_env)")
        return self

    def warnings(self) -> list[str]:
        if not self.enabled:
            return []
        found = []
        if "None" in self.security:
            passwords = ("user passwords in clear text too" if self.security == ["None"] else
                         "user passwords stay encrypted with the server certificate")
            found.append("opcua.security lists None: on that endpoint values and writes travel unsigned and "
                         f"unencrypted ({passwords}); keep it to a trusted network, or remove it")
        if self.allow_anonymous:
            found.append("opcua.allow_anonymous is true: anyone who reaches port "
                         f"{self.port} can read every value and try writes (the write policy still decides)")
        return found

    def read_users(self, environ: Mapping[str, str] | None = None) -> dict[str, str]:
        """Every user's password (ConfigError naming the user whose secret cannot be had)."""
        environ = os.environ if environ is None else environ
        passwords: dict[str, str] = {}
        problems = []
        for index, user in enumerate(self.users):
            where = f"opcua.users[{index}]"
            if user.password_env is not None:
                if user.password_env not in environ:
                    problems.append(f"{where}.password_env: environment variable {user.password_env} is not set")
                else:
                    passwords[user.username] = environ[user.password_env]
            elif user.password_file is not None:
                try:
                    passwords[user.username] = user.password_file.read_text(encoding="utf-8").rstrip("\r\n")
                except OSError as exc:
                    problems.append(f"{where}.password_file: cannot read {user.password_file}: {exc.strerror}")
        if problems:
            raise ConfigError(problems)
        return passwords


def opcua_secret_problems(data: object, environ: Mapping[str, str], secrets: bool = True) -> list[str]:
    """The users' passwords cannot be had (only when the server is enabled: a disabled section reads none).

    `secrets=False` (check-config --as-service) leaves them unread, as for the MQTT password: the unit hands
    the service its environment, not this shell."""
    if not secrets or not isinstance(data, dict):
        return []
    try:
        section = OpcUaConfig.model_validate(data)
    except ValueError:
        return []  # the schema errors are reported by the Config validation
    if not section.enabled:
        return []
    try:
        section.read_users(environ)
    except ConfigError as exc:
        return exc.problems
    return []
