"""Reliability tooling shipped with the cell: fault injection, fuzzing and soak benches.

Each module provides one ``cellctl bench`` measurement (see :mod:`cellctl.cli.bench`).
"""
