"""Skeleton prediction model (UniRig-style): training, ONNX export and checks."""
