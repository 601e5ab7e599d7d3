"""qlap-runtime: QLAP as an actor runtime. The algorithm lives in :mod:`qlap_runtime.qlap`."""

__version__ = "0.1.0"
