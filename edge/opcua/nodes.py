"""AddNodesItem builders: folders, objects, variables (with their EngineeringUnits), added in one batch.

The address space is built with the server's node management service directly (one call per machine
birth) rather than node by node through asyncua's high-level Node API, which awaits per node.
"""

from __future__ import annotations

from asyncua import ua

from edge.opcua.layout import describe_unit

UNITS_NAMESPACE = "http://www.opcfoundation.org/UA/units/un/cefact"
READ = ua.AccessLevel.CurrentRead.mask
READ_WRITE = ua.AccessLevel.CurrentRead.mask | ua.AccessLevel.CurrentWrite.mask

_HAS_COMPONENT = ua.NodeId(ua.ObjectIds.HasComponent)
_HAS_PROPERTY = ua.NodeId(ua.ObjectIds.HasProperty)
_ORGANIZES = ua.NodeId(ua.ObjectIds.Organizes)


def folder(node_id: ua.NodeId, name: str, parent: ua.NodeId, notifier: bool = False) -> ua.AddNodesItem:
    return _object(node_id, name, parent, ua.ObjectIds.FolderType, _ORGANIZES, notifier)


def component(node_id: ua.NodeId, name: str, parent: ua.NodeId, notifier: bool = False) -> ua.AddNodesItem:
    return _object(node_id, name, parent, ua.ObjectIds.BaseObjectType, _HAS_COMPONENT, notifier)


def _object(node_id: ua.NodeId, name: str, parent: ua.NodeId, type_id: int, reference: ua.NodeId,
            notifier: bool) -> ua.AddNodesItem:
    attrs = ua.ObjectAttributes()
    attrs.DisplayName = ua.LocalizedText(name)
    attrs.EventNotifier = ua.EventNotifier.SubscribeToEvents.mask if notifier else 0
    return _item(node_id, ua.QualifiedName(name, node_id.NamespaceIndex), ua.NodeClass.Object, parent, reference,
                 type_id, attrs)


def _item(node_id: ua.NodeId, browse_name: ua.QualifiedName, node_class: ua.NodeClass, parent: ua.NodeId,
          reference: ua.NodeId, type_id: int, attrs: object) -> ua.AddNodesItem:
    item = ua.AddNodesItem()
    item.RequestedNewNodeId = node_id
    item.BrowseName = browse_name
    item.NodeClass = node_class
    item.ParentNodeId = parent
    item.ReferenceTypeId = reference
    item.TypeDefinition = ua.NodeId(type_id)
    item.NodeAttributes = attrs
    return item


def variable(node_id: ua.NodeId, name: str, parent: ua.NodeId, vtype: ua.VariantType, value: ua.Variant,
             *, writable: bool = False, description: str | None = None,
             has_unit: bool = False) -> ua.AddNodesItem:
    """A scalar variable of built-in type `vtype` (BaseAnalogType where it has a unit, else
    BaseDataVariableType), a HasComponent of `parent`."""
    attrs = ua.VariableAttributes()
    attrs.DisplayName = ua.LocalizedText(name)
    if description:
        attrs.Description = ua.LocalizedText(description)
    attrs.Value = value
    attrs.DataType = ua.NodeId(vtype.value)
    attrs.ValueRank = ua.ValueRank.Scalar
    attrs.AccessLevel = attrs.UserAccessLevel = READ_WRITE if writable else READ
    return _item(node_id, ua.QualifiedName(name, node_id.NamespaceIndex), ua.NodeClass.Variable, parent,
                 _HAS_COMPONENT, ua.ObjectIds.BaseAnalogType if has_unit else ua.ObjectIds.BaseDataVariableType, attrs)


def engineering_units(node_id: ua.NodeId, parent: ua.NodeId, unit: str) -> ua.AddNodesItem:
    """The EngineeringUnits property (EUInformation, UNECE code where known) of a variable."""
    unit_id, description = describe_unit(unit)
    info = ua.EUInformation(NamespaceUri=UNITS_NAMESPACE, UnitId=unit_id, DisplayName=ua.LocalizedText(unit),
                            Description=ua.LocalizedText(description))
    attrs = ua.VariableAttributes()
    attrs.DisplayName = ua.LocalizedText("EngineeringUnits")
    attrs.Value = ua.Variant(info, ua.VariantType.ExtensionObject)
    attrs.DataType = ua.NodeId(ua.ObjectIds.EUInformation)
    attrs.ValueRank = ua.ValueRank.Scalar
    attrs.AccessLevel = attrs.UserAccessLevel = READ
    return _item(node_id, ua.QualifiedName("EngineeringUnits", 0), ua.NodeClass.Variable, parent, _HAS_PROPERTY,
                 ua.ObjectIds.PropertyType, attrs)
