"""A device's pipeline in the service: the one frame path (``firmware_protocol.frame_path``)
feeding the model's window and the inference worker."""
