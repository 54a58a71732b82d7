"""The operator HMI: web pages, REST API and live Foxglove view of one cell (``cellctl hmi``)."""

from cellctl.hmi.config import HmiConfig, load_hmi_config
from cellctl.hmi.server import Hmi, HmiServer, build_app

__all__ = ["Hmi", "HmiConfig", "HmiServer", "build_app", "load_hmi_config"]
