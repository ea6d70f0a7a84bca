"""Torch modules: separators f^B, f^M, f^R, encoders and policies; self-describing checkpoints."""
