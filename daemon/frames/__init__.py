"""A device's frame path in the service: bytes to paired frames to the model's window."""
