"""The OPC UA PackML gateway: OPC 30050 objects and PackTags for PLCs, a client of the Zenoh wire contract."""

from cellctl.gateway.opcua.config import DEFAULT_ENDPOINT, OpcuaConfig, load_gateway_config
from cellctl.gateway.opcua.server import APPLICATION_URI, OpcuaGateway
from cellctl.gateway.opcua.space import BASE_PARKED_METHOD, CELLCTL_NS, METHODS, PACKML_NS, VARIABLES

__all__ = [
    "APPLICATION_URI",
    "BASE_PARKED_METHOD",
    "CELLCTL_NS",
    "DEFAULT_ENDPOINT",
    "METHODS",
    "PACKML_NS",
    "VARIABLES",
    "OpcuaConfig",
    "OpcuaGateway",
    "load_gateway_config",
]
