//! The address space (docs/opcua.md): the printer as an OPC 40540 additive manufacturing
//! machine under `Objects/Machines`, as far as a monitor beside the machine knows it:
//! `Identification` (the printer's nameplate), `Components` (the camera, the monitor),
//! `Production/ActiveJob` (the build), `Monitoring/Process` (layer, phase, the plate's and the
//! parts' inspection values), `Monitoring/Health` (the daemon's parts) and `InspectionAlarm`
//! (an alarm condition a client acknowledges). Every node is in the namespace [`NAMESPACE`],
//! its id the path from `Machines` joined by `.` (`Printer.Monitoring.Process.CurrentLayer`).

use crate::config::opcua::{Nameplate, OpcuaConfig};
use opcua::server::address_space::{
    AddressSpace, EventNotifier, MethodBuilder, ObjectBuilder, VariableBuilder,
};
use opcua::types::{
    DataTypeId, LocalizedText, NodeId, ObjectId, ObjectTypeId, QualifiedName, VariableTypeId,
    Variant,
};

/// The namespace of every node the monitor adds.
pub const NAMESPACE: &str = "urn:layerwise:opcua";

/// The machine object's path, the root of every other.
pub const MACHINE: &str = "Printer";
pub const PROCESS: &str = "Printer.Monitoring.Process";
pub const PARTS: &str = "Printer.Monitoring.Process.Parts";
pub const PLATE: &str = "Printer.Monitoring.Process.Plate";
pub const HEALTH: &str = "Printer.Monitoring.Health";
pub const JOB: &str = "Printer.Production.ActiveJob";
pub const ALARM: &str = "Printer.InspectionAlarm";
pub const ACKNOWLEDGE: &str = "Printer.InspectionAlarm.Acknowledge";

/// A node's id from its path.
pub fn id(ns: u16, path: &str) -> NodeId {
    NodeId::new(ns, path)
}

/// Adds an object at `path` (its browse name the path's last part) under `parent`.
pub fn object(space: &mut AddressSpace, ns: u16, path: &str, parent: NodeId, organized: bool) {
    let name = path.rsplit('.').next().unwrap_or(path);
    let builder = ObjectBuilder::new(&id(ns, path), QualifiedName::new(ns, name), name)
        .has_type_definition(ObjectTypeId::BaseObjectType);
    let builder = if organized {
        builder.organized_by(parent)
    } else {
        builder.component_of(parent)
    };
    builder.insert(space);
}

/// Adds a read-only variable `path` under `parent` holding `value` (its data type).
pub fn variable(
    space: &mut AddressSpace,
    ns: u16,
    path: &str,
    parent: NodeId,
    value: impl Into<Variant>,
) {
    let value: Variant = value.into();
    let name = path.rsplit('.').next().unwrap_or(path);
    let data_type = value
        .data_type()
        .map(|t| t.node_id)
        .unwrap_or_else(|| DataTypeId::BaseDataType.into());
    VariableBuilder::new(&id(ns, path), QualifiedName::new(ns, name), name)
        .data_type(data_type)
        .value(value)
        .component_of(parent)
        .has_type_definition(VariableTypeId::BaseDataVariableType)
        .insert(space);
}

fn nameplate(space: &mut AddressSpace, ns: u16, path: &str, parent: NodeId, plate: &Nameplate) {
    object(space, ns, path, parent, false);
    let me = id(ns, path);
    let text = |s: &str| LocalizedText::new("", s);
    variable(
        space,
        ns,
        &format!("{path}.Manufacturer"),
        me.clone(),
        text(&plate.manufacturer),
    );
    variable(
        space,
        ns,
        &format!("{path}.Model"),
        me.clone(),
        text(&plate.model),
    );
    variable(
        space,
        ns,
        &format!("{path}.SerialNumber"),
        me,
        plate.serial_number.as_str(),
    );
}

/// Builds the static part of the address space; parts, plate values and health entries are
/// added as the daemon first reports them ([`super::model`]).
pub fn build(space: &mut AddressSpace, ns: u16, config: &OpcuaConfig) {
    space.add_folder(
        &id(ns, "Machines"),
        QualifiedName::new(ns, "Machines"),
        "Machines",
        &ObjectId::ObjectsFolder.into(),
    );
    ObjectBuilder::new(
        &id(ns, MACHINE),
        QualifiedName::new(ns, MACHINE),
        format!("{} {}", config.printer.manufacturer, config.printer.model),
    )
    .has_type_definition(ObjectTypeId::BaseObjectType)
    .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
    .organized_by(id(ns, "Machines"))
    .insert(space);
    let machine = id(ns, MACHINE);
    let ident = format!("{MACHINE}.Identification");
    nameplate(space, ns, &ident, machine.clone(), &config.printer);
    variable(
        space,
        ns,
        &format!("{ident}.ProductInstanceUri"),
        id(ns, &ident),
        format!(
            "urn:{}:{}:{}",
            config.printer.manufacturer, config.printer.model, config.printer.serial_number
        )
        .replace(' ', "-"),
    );
    let components = format!("{MACHINE}.Components");
    object(space, ns, &components, machine.clone(), false);
    let camera = format!("{components}.Camera");
    object(space, ns, &camera, id(ns, &components), false);
    nameplate(
        space,
        ns,
        &format!("{camera}.Identification"),
        id(ns, &camera),
        &config.camera,
    );
    let monitor = format!("{components}.Monitor");
    object(space, ns, &monitor, id(ns, &components), false);
    let monitor_ident = format!("{monitor}.Identification");
    nameplate(
        space,
        ns,
        &monitor_ident,
        id(ns, &monitor),
        &Nameplate {
            manufacturer: "layerwise".into(),
            model: "layerwise".into(),
            serial_number: String::new(),
        },
    );
    variable(
        space,
        ns,
        &format!("{monitor_ident}.SoftwareRevision"),
        id(ns, &monitor_ident),
        env!("CARGO_PKG_VERSION"),
    );

    let production = format!("{MACHINE}.Production");
    object(space, ns, &production, machine.clone(), false);
    object(space, ns, JOB, id(ns, &production), false);
    for (name, value) in [
        ("Name", Variant::from("")),
        ("Identifier", Variant::from("")),
        ("Program", Variant::from("")),
        ("State", Variant::from("NotStarted")),
        ("StartTime", Variant::from(opcua::types::DateTime::null())),
        ("EndTime", Variant::from(opcua::types::DateTime::null())),
        ("LayersExpected", Variant::from(0u32)),
    ] {
        variable(space, ns, &format!("{JOB}.{name}"), id(ns, JOB), value);
    }

    let monitoring = format!("{MACHINE}.Monitoring");
    object(space, ns, &monitoring, machine.clone(), false);
    object(space, ns, PROCESS, id(ns, &monitoring), false);
    for (name, value) in [
        ("CurrentLayer", Variant::from(0u32)),
        ("Phase", Variant::from("")),
        (
            "LastSignalTime",
            Variant::from(opcua::types::DateTime::null()),
        ),
        ("LayersInspected", Variant::from(0u32)),
    ] {
        variable(
            space,
            ns,
            &format!("{PROCESS}.{name}"),
            id(ns, PROCESS),
            value,
        );
    }
    object(space, ns, PLATE, id(ns, PROCESS), false);
    for (name, value) in [
        ("FlagsOnLastLayer", 0u32),
        ("WarningFlagsTotal", 0u32),
        ("CriticalFlagsTotal", 0u32),
    ] {
        variable(space, ns, &format!("{PLATE}.{name}"), id(ns, PLATE), value);
    }
    object(space, ns, PARTS, id(ns, PROCESS), false);
    object(space, ns, HEALTH, id(ns, &monitoring), false);
    variable(
        space,
        ns,
        &format!("{HEALTH}.DaemonState"),
        id(ns, HEALTH),
        "starting",
    );

    ObjectBuilder::new(
        &id(ns, ALARM),
        QualifiedName::new(ns, "InspectionAlarm"),
        "Inspection alarm",
    )
    .has_type_definition(ObjectTypeId::BaseObjectType)
    .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
    .component_of(machine)
    .insert(space);
    for (name, value) in [
        ("Active", Variant::from(false)),
        ("Acknowledged", Variant::from(false)),
        ("Layer", Variant::from(0u32)),
        ("Kind", Variant::from("")),
        ("Message", Variant::from("")),
        ("AcknowledgedBy", Variant::from("")),
        (
            "LastEventId",
            Variant::from(opcua::types::ByteString::null()),
        ),
    ] {
        variable(space, ns, &format!("{ALARM}.{name}"), id(ns, ALARM), value);
    }
    MethodBuilder::new(
        &id(ns, ACKNOWLEDGE),
        QualifiedName::new(ns, "Acknowledge"),
        "Acknowledge",
    )
    .component_of(id(ns, ALARM))
    .executable(true)
    .user_executable(true)
    .input_args(
        space,
        &id(ns, "Printer.InspectionAlarm.Acknowledge.InputArguments"),
        &[
            ("EventId", DataTypeId::ByteString).into(),
            ("Comment", DataTypeId::LocalizedText).into(),
        ],
    )
    .insert(space);
}
