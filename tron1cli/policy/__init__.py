"""Student policies as they deploy: the contract, loading (torch or ONNX), export."""
