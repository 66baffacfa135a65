"""Learned skin model (see model.py)."""
