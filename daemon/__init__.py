"""The asyncio service, in rooms that follow a frame's way through it.

- ``input``: where the bytes come from (serial port, replay, simulated board) and ``--record``
- ``frames``: a device's bytes to paired frames, handed to the window
- ``inference``: the window, the batched onnxruntime worker, repetitions
- ``mqtt``: the payload schemas, publishing, remote control
- ``outputs``: MCAP, Foxglove, LSL and the web view beside MQTT
- ``settings``: the one configuration model and its sections
- ``service``: the command line, devices, worker processes, systemd notify, counters
- ``tools``: what stands around the service (emulator CLI, demo, viewer, benches, soaks)

``errors`` (the one exception root) and ``waiting`` (backoff, waiting on events) are shared
by all of them.
"""
