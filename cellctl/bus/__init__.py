"""The Zenoh bus: session factory (``session``), key expressions (``keys``), message codec
(``codec``), request helper (``rpc``). Import the submodules directly."""

__all__: list[str] = []
