"""torch -> ONNX export, parity checks, the model manifest. Filled by the network issues."""
