"""`mqtt:` the broker, TLS, login, Sparkplug ids and JSON topics.

Secrets never live in the file: the password comes from an environment variable (`password_env`) or a
file (`password_file`, e.g. a systemd or Docker secret); a literal `password:` key is refused.
`_mqtt_rules` states the rules between keys once, for the model validator and for load's re-check on the
raw data.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BeforeValidator, ConfigDict, Field, field_validator, model_validator

from edge import ConfigError
from edge.config.fields import HostName, SparkplugId, _at, _Model, check_file

Format = Literal["sparkplug", "json"]
FORMATS: tuple[Format, ...] = ("sparkplug", "json")


class TlsConfig(_Model):
    ca_file: Path | None = None
    cert_file: Path | None = None
    key_file: Path | None = None
    insecure_skip_verify: bool = False

    @field_validator("ca_file", "cert_file", "key_file")
    @classmethod
    def _readable(cls, value: Path | None) -> Path | None:
        return check_file(value)

    @model_validator(mode="after")
    def _key_needs_cert(self) -> TlsConfig:
        if self.key_file is not None and self.cert_file is None:
            raise _at("key_file", "a client key needs cert_file too")
        return self


class SparkplugConfig(_Model):
    group_id: SparkplugId
    edge_node_id: SparkplugId
    primary_host_id: SparkplugId | None = None


class JsonConfig(_Model):
    prefix: str | None = None  # default: focas/<group_id>/<edge_node_id> (MqttConfig.json_prefix)

    @field_validator("prefix")
    @classmethod
    def _topic_prefix(cls, value: str | None) -> str | None:
        if value is None:
            return None
        if not value or value.startswith("/") or value.endswith("/") or "//" in value:
            raise ValueError(f"{value!r}: expected topic levels like 'plant1/focas', no empty level")
        if "+" in value or "#" in value:
            raise ValueError(f"{value!r}: a topic prefix may not contain MQTT wildcards + #")
        return value


def _protocol(value: object) -> object:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return {5: "5", 3.1: "3.1.1"}.get(value, str(value))
    return {"5.0": "5", "311": "3.1.1", "v5": "5"}.get(str(value), value)


class MqttConfig(_Model):
    host: HostName = "localhost"
    port: int | None = Field(default=None, ge=1, le=65535)
    tls: TlsConfig | None = None
    username: str | None = None
    password: object = Field(default=None, exclude=True, repr=False)
    password_env: str | None = None
    password_file: Path | None = None
    protocol: Annotated[Literal["3.1.1", "5"], BeforeValidator(_protocol)] = "3.1.1"
    keepalive: int = Field(default=30, ge=5, le=65535)
    client_id: str | None = None
    formats: list[Format] = Field(default_factory=lambda: list(FORMATS))
    sparkplug: SparkplugConfig | None = None
    json_topics: JsonConfig = Field(default_factory=JsonConfig, alias="json")

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    @field_validator("password")
    @classmethod
    def _no_literal_password(cls, value: object) -> None:
        if value is not None:
            raise ValueError("secrets do not belong in the config file (it gets copied, committed and "
                             "logged); use password_env: VARIABLE or password_file: /run/secrets/NAME")
        return None

    @field_validator("formats")
    @classmethod
    def _formats(cls, value: list[str]) -> list[str]:
        if not value:
            raise ValueError("at least one of sparkplug, json")
        if len(set(value)) != len(value):
            raise ValueError(f"{value}: a format is listed twice")
        return value

    @model_validator(mode="after")
    def _consistent(self) -> MqttConfig:
        for key, message in _mqtt_rules(self.formats, self.sparkplug, self.password_env, self.password_file,
                                        self.username):
            raise _at(key, message)
        return self

    @property
    def json_prefix(self) -> str:
        """`json.prefix`, or one naming this gateway, so two gateways never share retained topics."""
        if self.json_topics.prefix is not None:
            return self.json_topics.prefix
        return default_json_prefix(self.sparkplug)

    @property
    def effective_port(self) -> int:
        return self.port or (8883 if self.tls else 1883)

    def read_password(self, environ: Mapping[str, str] | None = None) -> str | None:
        """The MQTT password from its environment variable or file; ConfigError if it cannot be had."""
        return read_secret(self.password_env, self.password_file, environ)


def gateway_name() -> str:
    """The host name, as one topic level: the gateway's identity when the config names none."""
    name = socket.gethostname().replace("+", "_").replace("#", "_").replace("/", "_")
    return name or "gateway"


def default_json_prefix(sparkplug: SparkplugConfig | None) -> str:
    """focas/<group_id>/<edge_node_id>; without Sparkplug ids (JSON only) focas/<host name>."""
    if sparkplug is not None:
        return f"focas/{sparkplug.group_id}/{sparkplug.edge_node_id}"
    return f"focas/{gateway_name()}"


def read_secret(password_env: object, password_file: object, environ: Mapping[str, str] | None = None) -> str | None:
    """The MQTT password from an environment variable or a file; ConfigError naming the key if it cannot be had."""
    environ = os.environ if environ is None else environ
    if isinstance(password_env, str) and password_env:
        if password_env not in environ:
            raise ConfigError([f"mqtt.password_env: environment variable {password_env} is not set"])
        return environ[password_env]
    if isinstance(password_file, str | Path) and str(password_file):
        try:
            return Path(password_file).read_text(encoding="utf-8").rstrip("\r\n")
        except OSError as exc:
            credential = Path("/run/credentials") in Path(password_file).parents
            hint = (" (a systemd credential: it exists only inside the service whose unit loads it with "
                    "LoadCredential=; check it with check-config --as-service)") if credential else ""
            raise ConfigError([f"mqtt.password_file: cannot read {password_file}: {exc.strerror}{hint}"]) from exc
    return None


def _mqtt_rules(formats: object, sparkplug: object, password_env: object,
                password_file: object, username: object) -> list[tuple[str, str]]:
    """Rules between mqtt keys as (key, message): one source for the model validator and for the raw
    re-check in load."""
    rules = []
    if isinstance(formats, list) and "sparkplug" in formats and sparkplug is None:
        rules.append(("sparkplug", "required (group_id, edge_node_id) when formats includes sparkplug"))
    if password_env and password_file:
        rules.append(("password_file", "give password_env or password_file, not both"))
    if (password_env or password_file) and not username:
        rules.append(("username", "a password needs a username"))
    return rules
