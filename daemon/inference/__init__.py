"""The model in the service: the window of embedded frames, the batched onnxruntime
worker shared by every device, and repetitions counted from its progress."""
