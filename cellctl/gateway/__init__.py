"""Protocol gateways: the cell's wire contract spoken in a plant's own protocols (each its own process)."""

__all__: list[str] = []
