"""Cleaning methods behind one interface (see ``registry``)."""

from mocapnet.methods.registry import Method, MethodContext, available, build_method, register

__all__ = ["Method", "MethodContext", "available", "build_method", "register"]
