"""The daemon's public API: payload schemas, building them, publishing them to the broker,
and remote control requests over MQTT."""
