//! CANopen (CiA 301) for the rover's wheel drives and pan-tilt head, on 11-bit ids beside the
//! team link's 29-bit frames on the same bus.
//!
//! - [`frame`]: the messages (NMT, SYNC, EMCY, PDO, expedited SDO, heartbeat) and their total
//!   decoder;
//! - [`device`]: the devices as the simulator and the HIL harness emulate them
//!   ([`WheelDriveNode`], [`PanTiltNode`]), state machines on the caller's clock;
//! - [`master`]: [`CanopenMaster`], which the firmware's driver runs over any `CanBus`: NMT,
//!   SYNC, heartbeat supervision, the drives' encoder cycles and the head's angles;
//! - [`kinematics`]: wheel speeds from a body twist and back ([`SkidSteerKinematics`]).
//!
//! Times are `now_ns: u64` on a monotonic clock the caller chooses (simulated or wall).

pub mod device;
pub mod frame;
pub mod kinematics;
pub mod master;

pub use device::{
    CanopenDevice, DeviceConfig, PAN_TILT_NODE, PanTiltConfig, PanTiltNode, WHEEL_DRIVE_NODES, WheelDriveConfig,
    WheelDriveNode, service_devices,
};
pub use frame::{
    CanopenDecodeError, CanopenMessage, Emergency, NmtCommand, NmtState, NmtTarget, NodeId, PdoData, PdoNumber,
    SdoData, SdoRequest, SdoResponse,
};
pub use kinematics::SkidSteerKinematics;
pub use master::{
    CanopenMaster, HeadAngles, MasterConfig, MasterCounters, MasterError, MasterEvent, NodeHealth, WHEELS,
    WheelEncoders,
};
