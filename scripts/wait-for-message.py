"""Wait for one MQTT message matching a topic filter; print its topic and exit 0, or exit 1 on timeout.

Used by `make systemd-check` and `make arm64-check` inside their Debian roots, with the installed venv's
python (paho-mqtt is a dependency there): wait-for-message.py HOST PORT FILTER TIMEOUT_S
"""

from __future__ import annotations

import sys
import threading

import paho.mqtt.client as mqtt


def main(host: str, port: str, topic_filter: str, timeout_s: str) -> int:
    got = threading.Event()
    topics: list[str] = []
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    client.on_connect = lambda c, *_: c.subscribe(topic_filter)

    def on_message(_c: mqtt.Client, _u: object, message: mqtt.MQTTMessage) -> None:
        topics.append(message.topic)
        got.set()

    client.on_message = on_message
    client.connect(host, int(port))
    client.loop_start()
    try:
        if not got.wait(float(timeout_s)):
            print(f"no message on {topic_filter} within {timeout_s}s", file=sys.stderr)
            return 1
        print(topics[0])
        return 0
    finally:
        client.loop_stop()
        client.disconnect()


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:5]))
