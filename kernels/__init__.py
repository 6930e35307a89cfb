"""Batched tensor kernels: pure functions of tensors, batch dimension first. Installed as ``sagp_batched_kernels``."""
