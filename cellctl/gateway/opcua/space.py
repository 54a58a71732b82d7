"""The OPC UA address space of one cell: OPC 30050 names where the spec has them, PackTags where PLCs need flat tags.

Every node's NodeId is ``ns=<cellctl>;s=<cell>/<path>`` (the browse path spelt with ``/``), so a
PLC project can hold NodeIds that survive a gateway restart. BrowseNames that OPC 30050 defines
are in the PackML namespace; PackTags and cellctl additions are in the cellctl namespace
(docs/opcua.md has the table).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from asyncua import Node, Server, ua

from cellctl.bus.keys import ROLES
from cellctl.messages import LastCycle, PackMLCommand
from cellctl.seen import VERDICTS
from cellctl.surface import SURFACES

__all__ = [
    "BASE_PARKED_METHOD",
    "CELLCTL_NS",
    "METHODS",
    "PACKML_NS",
    "VARIABLES",
    "CellSpace",
    "VarSpec",
    "build_cell_space",
]

PACKML_NS = "http://opcfoundation.org/UA/PackML/"
CELLCTL_NS = "urn:cellctl:opcua"

_PACKML_NAMES = frozenset(
    {
        "Status", "Admin", "BaseStateMachine", "SetUnitMode",
        "UnitModeCurrent", "StateRequested", "StateChangeInProcess", "MachSpeed", "CurMachSpeed",
        "EquipmentBlocked", "EquipmentStarved",
        "ProdProcessedCount", "ProdDefectiveCount", "StopReason", "Warning",
        "Reset", "Start", "Stop", "Hold", "Unhold", "Suspend", "Unsuspend", "Abort", "Clear", "ToComplete",
    }
)  # fmt: skip
"""BrowseNames OPC 30050 v1.01 defines (PackMLBaseObjectType, its Status/Admin objects, state-machine methods)."""

METHODS: dict[str, PackMLCommand] = {
    "Reset": PackMLCommand.reset,
    "Start": PackMLCommand.start,
    "Stop": PackMLCommand.stop,
    "Hold": PackMLCommand.hold,
    "Unhold": PackMLCommand.unhold,
    "Suspend": PackMLCommand.suspend,
    "Unsuspend": PackMLCommand.unsuspend,
    "Abort": PackMLCommand.abort,
    "Clear": PackMLCommand.clear,
    "ToComplete": PackMLCommand.complete,  # OPC 30050 6.7.9 names the Complete command's method ToComplete
}
"""Method BrowseName on ``BaseStateMachine`` → the PackML command it sends."""

BASE_PARKED_METHOD = "ConfirmBaseParked"
"""Method on the cell object: a manual base (``base.backend: manual``) is parked at station k — the
``base_parked`` Command a PLC or operator sends (a cellctl addition, not OPC 30050)."""

V = ua.VariantType


@dataclass(frozen=True)
class VarSpec:
    path: str
    vtype: ua.VariantType
    initial: Any
    writable: bool = False
    description: str = ""


VARIABLES: tuple[VarSpec, ...] = (
    VarSpec("Status/StateCurrent", V.Int32, 0, description="PackTags StateCurrent, TR88 code (0: daemon down)"),
    VarSpec("Status/StateName", V.String, "Undefined", description="the PackML state's name"),
    VarSpec("Status/StateRequested", V.Int32, 0, description="state the last accepted command entered (TR88 code)"),
    VarSpec("Status/StateChangeInProcess", V.Boolean, False, description="true in acting states (…ing)"),
    VarSpec("Status/UnitModeCurrent", V.Int32, 0, description="1 Production, 2 Maintenance, 3 Manual (0: down)"),
    VarSpec("Status/Step", V.String, "", description="inspection-cycle step inside Execute"),
    VarSpec("Status/CycleId", V.String, ""),
    VarSpec("Status/AvailableCommands", V.String, [], description="PackML commands the current state accepts"),
    VarSpec("Status/CmdAccepted", V.Boolean, False, description="result of the last command (method or handshake)"),
    VarSpec("Status/CmdRejectReason", V.String, "", description="why the last command was refused ('' if accepted)"),
    VarSpec("Status/DaemonConnected", V.Boolean, False),
    VarSpec("Status/UnavailableReason", V.String, "", description="why StateCurrent is 0"),
    VarSpec("Status/MachSpeed", V.Float, 0.0, description="OPC 30050 mandatory; the cell has no speed setpoint"),
    VarSpec("Status/CurMachSpeed", V.Float, 0.0, description="OPC 30050 mandatory; always 0"),
    VarSpec("Status/EquipmentBlocked", V.Boolean, False, description="OPC 30050 mandatory; always false"),
    VarSpec("Status/EquipmentStarved", V.Boolean, False, description="OPC 30050 mandatory; always false"),
    VarSpec("Admin/ProdProcessedCount", V.Int32, 0, description="bins inspected (cycles completed)"),
    VarSpec("Admin/ProdDefectiveCount", V.Int32, 0, description="of those, verdict dirty"),
    VarSpec("Admin/StopReason", V.String, "", description="why the cell last went to Stopped/Aborted/Held"),
    VarSpec("Admin/Warning", V.String, [], description="current warnings"),
    VarSpec("Admin/LastError", V.String, ""),
    VarSpec("Admin/LoginFailures", V.UInt32, 0, description="wrong OPC UA passwords since the gateway started"),
    VarSpec("Admin/LoginsThrottled", V.UInt32, 0, description="logins refused unchecked during a back-off"),
    *(VarSpec(f"Admin/Workers/{r}", V.Boolean, False, description=f"{r} worker alive") for r in ROLES),
    VarSpec("Admin/LastCycle/CycleId", V.String, ""),
    VarSpec("Admin/LastCycle/Outcome", V.String, ""),
    VarSpec("Admin/LastCycle/Verdict", V.String, "", description=f"'', {', '.join(VERDICTS)}"),
    VarSpec("Admin/LastCycle/Coverage", V.Double, 0.0),
    VarSpec("Admin/LastCycle/Finished", V.String, ""),
    *(VarSpec(f"Admin/LastCycle/Seen/{s}", V.Double, -1.0, description=f"share of the {s} surface seen (-1: "
              "unknown)") for s in SURFACES),
    *(VarSpec(f"Admin/LastCycle/MinSeen/{s}", V.Double, 0.0, description=f"share of the {s} surface 'clean' "
              "needs (below it: 'incomplete')") for s in SURFACES),
    VarSpec("Command/CntrlCmd", V.Int32, 0, True, "CntrlCmd 1 Reset … 10 Complete, then CmdChangeRequest"),
    VarSpec("Command/CmdChangeRequest", V.Boolean, False, True, "true: the gateway sends CntrlCmd, then resets it"),
    VarSpec("Command/UnitMode", V.Int32, 0, True, "requested unit mode 1..3; then set UnitModeChangeRequest"),
    VarSpec("Command/UnitModeChangeRequest", V.Boolean, False, True, "write true: the gateway sends UnitMode"),
    VarSpec("Command/Parameter/Mode", V.String, "", True, "Start param mode: '' (evaluate), evaluate, collect"),
    VarSpec("Command/Parameter/Surface", V.String, "", True, "Start param surface: '', external, internal"),
    VarSpec("Command/Parameter/Label", V.String, "", True, "Start param label (collect): '', clean, dirty"),
)  # fmt: skip
"""Every variable under a cell object, by path; the Command ones are the only writable nodes."""


def last_cycle_values(last: LastCycle) -> list[tuple[str, Any]]:
    """The ``Admin/LastCycle/*`` values of a finished cycle (from a Status's admin or a CycleResult)."""
    seen = last.coverage_by_surface or {}
    need = last.min_seen_fraction or {}
    return [
        ("Admin/LastCycle/CycleId", last.cycle_id),
        ("Admin/LastCycle/Outcome", last.outcome),
        ("Admin/LastCycle/Verdict", last.verdict or ""),
        ("Admin/LastCycle/Coverage", float(last.coverage or 0.0)),
        ("Admin/LastCycle/Finished", last.finished),
        *((f"Admin/LastCycle/Seen/{s}", float(seen[s]) if seen.get(s) is not None else -1.0) for s in SURFACES),
        *((f"Admin/LastCycle/MinSeen/{s}", float(need.get(s, 0.0))) for s in SURFACES),
    ]


@dataclass
class CellSpace:
    """The nodes of one cell, by path relative to the cell object."""

    cell: str
    obj: Node
    state_machine: Node
    ns: int
    vars: dict[str, Node] = field(default_factory=dict)
    methods: dict[str, Node] = field(default_factory=dict)

    def nodeid(self, path: str) -> ua.NodeId:
        return ua.NodeId(f"{self.cell}/{path}", self.ns)


def _qname(name: str, pk: int, cc: int) -> ua.QualifiedName:
    return ua.QualifiedName(name, pk if name in _PACKML_NAMES else cc)


def _is_array(spec: VarSpec) -> bool:
    return isinstance(spec.initial, list)


async def build_cell_space(
    server: Server, cell: str, pk: int, cc: int, methods: Any, set_unit_mode: Any, confirm_base_parked: Any
) -> CellSpace:
    """Create the cell object under Objects with every variable and method.

    Args:
        pk, cc: namespace indexes of the PackML and cellctl namespaces.
        methods: ``methods(cell, name)`` → the coroutine serving method ``name`` of ``BaseStateMachine``.
        set_unit_mode: the coroutine serving ``SetUnitMode``.
        confirm_base_parked: the coroutine serving ``ConfirmBaseParked`` (a manual base's park confirmation).
    """
    objects = server.nodes.objects
    obj = await objects.add_object(ua.NodeId(cell, cc), ua.QualifiedName(cell, cc))
    await obj.write_attribute(
        ua.AttributeIds.Description,
        ua.DataValue(ua.Variant(ua.LocalizedText(f"PackML unit: inspection cell {cell}"), V.LocalizedText)),
    )
    folders: dict[str, Node] = {"": obj}

    async def folder(path: str) -> Node:
        if path not in folders:
            parent_path, _, name = path.rpartition("/")
            parent = await folder(parent_path)
            folders[path] = await parent.add_object(ua.NodeId(f"{cell}/{path}", cc), _qname(name, pk, cc))
        return folders[path]

    space = CellSpace(cell, obj, await folder("BaseStateMachine"), cc)
    for spec in VARIABLES:
        parent_path, _, name = spec.path.rpartition("/")
        parent = await folder(parent_path)
        var = await parent.add_variable(
            space.nodeid(spec.path),
            _qname(name, pk, cc),
            ua.Variant(spec.initial, spec.vtype, is_array=_is_array(spec)),
        )
        if _is_array(spec):
            await var.write_attribute(ua.AttributeIds.ValueRank, ua.DataValue(ua.Variant(1, V.Int32)))
        if spec.description:
            await var.write_attribute(
                ua.AttributeIds.Description,
                ua.DataValue(ua.Variant(ua.LocalizedText(spec.description), V.LocalizedText)),
            )
        if spec.writable:
            await var.set_writable(True)
        space.vars[spec.path] = var
    current = await space.state_machine.add_variable(
        ua.NodeId(f"{cell}/BaseStateMachine/CurrentState", cc),
        ua.QualifiedName("CurrentState", 0),
        ua.Variant(ua.LocalizedText("Undefined"), V.LocalizedText),
    )
    space.vars["BaseStateMachine/CurrentState"] = current
    reason = ua.Argument(Name="Reason", DataType=ua.NodeId(ua.ObjectIds.String), ValueRank=-1)
    reason.Description = ua.LocalizedText("why the command was refused; '' when accepted")
    for name in METHODS:
        space.methods[name] = await space.state_machine.add_method(
            ua.NodeId(f"{cell}/BaseStateMachine/{name}", cc), _qname(name, pk, cc), methods(cell, name), [], [reason]
        )
    mode_arg = ua.Argument(Name="UnitMode", DataType=ua.NodeId(ua.ObjectIds.Int32), ValueRank=-1)
    mode_arg.Description = ua.LocalizedText("1 Production, 2 Maintenance, 3 Manual")
    space.methods["SetUnitMode"] = await obj.add_method(
        ua.NodeId(f"{cell}/SetUnitMode", cc), _qname("SetUnitMode", pk, cc), set_unit_mode(cell), [mode_arg], [reason]
    )
    station_arg = ua.Argument(Name="Station", DataType=ua.NodeId(ua.ObjectIds.Int32), ValueRank=-1)
    station_arg.Description = ua.LocalizedText("the station (>= 0) the base was parked at, as the cycle awaits it")
    space.methods[BASE_PARKED_METHOD] = await obj.add_method(
        ua.NodeId(f"{cell}/{BASE_PARKED_METHOD}", cc),
        _qname(BASE_PARKED_METHOD, pk, cc),
        confirm_base_parked(cell),
        [station_arg],
        [reason],
    )
    return space
