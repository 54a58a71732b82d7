"""cellctl: supervisor daemon and workers for an autonomous bin-cleanliness inspection cell."""

__version__ = "0.1.0"
__all__ = ["__version__"]
