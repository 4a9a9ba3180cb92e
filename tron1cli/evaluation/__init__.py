"""Evaluation protocols of the paper (Table I, Fig. 5, Fig. 6) over checkpoints or ONNX files."""
