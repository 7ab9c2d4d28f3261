//! CiA 301 messages of the predefined connection set on 11-bit ids: decoding from and encoding
//! to [`CanFrame`].
//!
//! ```text
//! id              message         data
//! 0x000           NMT             command u8, node u8 (0 = all)
//! 0x080           SYNC            nothing, or counter u8
//! 0x080 + node    EMCY            error code u16 LE, error register u8, 5 manufacturer bytes
//! 0x180 + node    TPDO1           0..=8 bytes (likewise 0x280 TPDO2, 0x380 TPDO3, 0x480 TPDO4)
//! 0x200 + node    RPDO1           0..=8 bytes (likewise 0x300 RPDO2, 0x400 RPDO3, 0x500 RPDO4)
//! 0x580 + node    SDO response    8 bytes: command u8, index u16 LE, sub-index u8, 4 bytes
//! 0x600 + node    SDO request     8 bytes, same layout
//! 0x700 + node    heartbeat       state u8 (0x00 boot-up, 0x04, 0x05, 0x7F)
//! ```
//!
//! Node ids are 1..=127. Decoding is total: every frame gives a message or a
//! [`CanopenDecodeError`], which tells a frame of another protocol on the bus
//! ([`CanopenDecodeError::is_foreign`]: extended ids, ids outside the set, TIME and LSS, which we
//! do not use) from a CANopen frame with bad content.
//!
//! Node guarding is not used (heartbeats only): a guarding reply, whose state byte has the toggle
//! bit 7 set, decodes as a malformed heartbeat.
//!
//! Only the expedited SDO transfers (at most 4 bytes, all our objects need) and the abort are
//! decoded; segmented and block transfers come out as `Unsupported` with their raw bytes, so a
//! server can refuse them with an abort instead of staying silent.

use std::fmt;

use crate::can::CanFrame;

/// Id of NMT commands.
pub const NMT_ID: u16 = 0x000;
/// Id of SYNC.
pub const SYNC_ID: u16 = 0x080;
const EMCY_BASE: u16 = 0x080;
const TPDO_BASE: [u16; 4] = [0x180, 0x280, 0x380, 0x480];
const RPDO_BASE: [u16; 4] = [0x200, 0x300, 0x400, 0x500];
/// Server → client ("transmit SDO" of the server).
const SDO_RESPONSE_BASE: u16 = 0x580;
/// Client → server.
const SDO_REQUEST_BASE: u16 = 0x600;
const HEARTBEAT_BASE: u16 = 0x700;
/// The function-code bits of an 11-bit id; the low 7 bits are the node id.
const FUNCTION_MASK: u16 = 0x780;
const NODE_MASK: u16 = 0x07F;
const STANDARD_ID_MAX: u32 = 0x7FF;

/// Every SDO frame has 8 bytes, used or not (CiA 301 §7.2.4.3).
pub const SDO_FRAME_LEN: usize = 8;
/// An EMCY frame has 8 bytes.
pub const EMCY_FRAME_LEN: usize = 8;
/// Most data bytes of a (classic CAN) PDO.
pub const PDO_MAX_LEN: usize = 8;

const SDO_CCS_DOWNLOAD: u8 = 1;
const SDO_CCS_UPLOAD: u8 = 2;
const SDO_SCS_UPLOAD: u8 = 2;
const SDO_SCS_DOWNLOAD: u8 = 3;
const SDO_CS_ABORT: u8 = 4;
const SDO_EXPEDITED: u8 = 0x02;
const SDO_SIZE_INDICATED: u8 = 0x01;

/// A CANopen node id, 1..=127.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(u8);

impl NodeId {
    pub const MIN: u8 = 1;
    pub const MAX: u8 = 127;

    /// `None` outside 1..=127 (0 addresses all nodes in NMT and is not a node).
    pub const fn new(id: u8) -> Option<NodeId> {
        if id >= Self::MIN && id <= Self::MAX { Some(NodeId(id)) } else { None }
    }

    /// For constants whose value is known to be valid: out-of-range ids fail to compile there.
    pub(crate) const fn from_const(id: u8) -> NodeId {
        assert!(id >= Self::MIN && id <= Self::MAX, "CANopen node ids are 1..=127");
        NodeId(id)
    }

    pub const fn get(self) -> u8 {
        self.0
    }
}

impl fmt::Display for NodeId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:#04x}", self.0)
    }
}

/// An NMT command (CiA 301 §7.2.8.3.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtCommand {
    Start,
    Stop,
    EnterPreOperational,
    ResetNode,
    ResetCommunication,
}

impl NmtCommand {
    pub const fn byte(self) -> u8 {
        match self {
            NmtCommand::Start => 0x01,
            NmtCommand::Stop => 0x02,
            NmtCommand::EnterPreOperational => 0x80,
            NmtCommand::ResetNode => 0x81,
            NmtCommand::ResetCommunication => 0x82,
        }
    }

    pub const fn from_byte(byte: u8) -> Option<NmtCommand> {
        match byte {
            0x01 => Some(NmtCommand::Start),
            0x02 => Some(NmtCommand::Stop),
            0x80 => Some(NmtCommand::EnterPreOperational),
            0x81 => Some(NmtCommand::ResetNode),
            0x82 => Some(NmtCommand::ResetCommunication),
            _ => None,
        }
    }
}

/// Whom an NMT command addresses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtTarget {
    /// Node id 0 on the wire.
    All,
    Node(NodeId),
}

impl NmtTarget {
    pub fn addresses(self, node: NodeId) -> bool {
        match self {
            NmtTarget::All => true,
            NmtTarget::Node(target) => target == node,
        }
    }
}

/// The state a heartbeat reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtState {
    /// The boot-up message: the node has just finished initialising (and is now pre-operational).
    BootUp,
    Stopped,
    Operational,
    PreOperational,
}

impl NmtState {
    pub const fn byte(self) -> u8 {
        match self {
            NmtState::BootUp => 0x00,
            NmtState::Stopped => 0x04,
            NmtState::Operational => 0x05,
            NmtState::PreOperational => 0x7F,
        }
    }

    pub const fn from_byte(byte: u8) -> Option<NmtState> {
        match byte {
            0x00 => Some(NmtState::BootUp),
            0x04 => Some(NmtState::Stopped),
            0x05 => Some(NmtState::Operational),
            0x7F => Some(NmtState::PreOperational),
            _ => None,
        }
    }
}

/// Which of the four default PDOs of a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PdoNumber {
    Pdo1,
    Pdo2,
    Pdo3,
    Pdo4,
}

impl PdoNumber {
    pub const ALL: [PdoNumber; 4] = [PdoNumber::Pdo1, PdoNumber::Pdo2, PdoNumber::Pdo3, PdoNumber::Pdo4];

    const fn index(self) -> usize {
        match self {
            PdoNumber::Pdo1 => 0,
            PdoNumber::Pdo2 => 1,
            PdoNumber::Pdo3 => 2,
            PdoNumber::Pdo4 => 3,
        }
    }
}

/// The 0..=8 data bytes of a PDO.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PdoData {
    len: u8,
    bytes: [u8; PDO_MAX_LEN],
}

impl PdoData {
    /// `None` for more than 8 bytes.
    pub fn new(data: &[u8]) -> Option<PdoData> {
        let mut bytes = [0; PDO_MAX_LEN];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(PdoData { len: data.len() as u8, bytes })
    }

    /// A full 8-byte PDO.
    pub const fn from_array(bytes: [u8; PDO_MAX_LEN]) -> PdoData {
        PdoData { len: PDO_MAX_LEN as u8, bytes }
    }

    /// Two `i32` little-endian, the layout of all our PDOs.
    pub fn from_i32_pair(first: i32, second: i32) -> PdoData {
        let mut bytes = [0; PDO_MAX_LEN];
        bytes[..4].copy_from_slice(&first.to_le_bytes());
        bytes[4..].copy_from_slice(&second.to_le_bytes());
        PdoData::from_array(bytes)
    }

    /// The two little-endian `i32` of an 8-byte PDO; `None` for any other length.
    pub fn i32_pair(&self) -> Option<(i32, i32)> {
        if usize::from(self.len) != PDO_MAX_LEN {
            return None;
        }
        let [a0, a1, a2, a3, b0, b1, b2, b3] = self.bytes;
        Some((i32::from_le_bytes([a0, a1, a2, a3]), i32::from_le_bytes([b0, b1, b2, b3])))
    }

    pub fn as_slice(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&self.bytes)
    }
}

/// The payload of an EMCY message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Emergency {
    /// CiA 301 error code; 0x0000 = error reset (the node has no error any more).
    pub error_code: u16,
    /// Object 0x1001: bit 0 generic, 1 current, 2 voltage, 3 temperature, 4 communication.
    pub error_register: u8,
    pub manufacturer: [u8; 5],
}

/// The 1..=4 data bytes of an expedited SDO transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SdoData {
    len: u8,
    bytes: [u8; 4],
}

impl SdoData {
    /// `None` for 0 or more than 4 bytes (an expedited transfer carries 1..=4).
    pub fn new(data: &[u8]) -> Option<SdoData> {
        if data.is_empty() {
            return None;
        }
        let mut bytes = [0; 4];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(SdoData { len: data.len() as u8, bytes })
    }

    pub fn from_u8(value: u8) -> SdoData {
        SdoData { len: 1, bytes: [value, 0, 0, 0] }
    }

    pub fn from_u16(value: u16) -> SdoData {
        let [b0, b1] = value.to_le_bytes();
        SdoData { len: 2, bytes: [b0, b1, 0, 0] }
    }

    pub fn from_u32(value: u32) -> SdoData {
        SdoData { len: 4, bytes: value.to_le_bytes() }
    }

    /// The value as an unsigned little-endian integer of its length.
    pub fn to_u32(&self) -> u32 {
        u32::from_le_bytes(self.bytes)
    }

    pub fn as_slice(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&self.bytes)
    }
}

/// Client → server (id 0x600 + node).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SdoRequest {
    /// Initiate upload: "send me object index:subindex".
    Upload {
        index: u16,
        subindex: u8,
    },
    /// Expedited download: "write these bytes to index:subindex".
    Download {
        index: u16,
        subindex: u8,
        data: SdoData,
    },
    Abort {
        index: u16,
        subindex: u8,
        code: u32,
    },
    /// Segmented or block transfer frames, kept raw.
    Unsupported([u8; SDO_FRAME_LEN]),
}

/// Server → client (id 0x580 + node).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SdoResponse {
    /// Expedited upload response carrying the object's value.
    Upload {
        index: u16,
        subindex: u8,
        data: SdoData,
    },
    /// The download was done.
    DownloadAck {
        index: u16,
        subindex: u8,
    },
    Abort {
        index: u16,
        subindex: u8,
        code: u32,
    },
    /// Segmented or block transfer frames, kept raw.
    Unsupported([u8; SDO_FRAME_LEN]),
}

/// SDO abort codes (CiA 301 §7.2.4.3.17) our server uses.
pub mod abort_code {
    /// Client/server command specifier not valid or unknown.
    pub const COMMAND_UNKNOWN: u32 = 0x0504_0001;
    /// Attempt to write a read only object.
    pub const READ_ONLY: u32 = 0x0601_0002;
    /// Object does not exist in the object dictionary.
    pub const NO_OBJECT: u32 = 0x0602_0000;
    /// Data type does not match, length of service parameter does not match.
    pub const LENGTH_MISMATCH: u32 = 0x0607_0010;
    /// Sub-index does not exist.
    pub const NO_SUBINDEX: u32 = 0x0609_0011;
}

/// One CANopen message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CanopenMessage {
    Nmt {
        command: NmtCommand,
        target: NmtTarget,
    },
    Sync {
        counter: Option<u8>,
    },
    Emergency {
        node: NodeId,
        emergency: Emergency,
    },
    Tpdo {
        node: NodeId,
        number: PdoNumber,
        data: PdoData,
    },
    Rpdo {
        node: NodeId,
        number: PdoNumber,
        data: PdoData,
    },
    SdoRequest {
        node: NodeId,
        request: SdoRequest,
    },
    SdoResponse {
        node: NodeId,
        response: SdoResponse,
    },
    /// Heartbeat, or boot-up with [`NmtState::BootUp`].
    Heartbeat {
        node: NodeId,
        state: NmtState,
    },
}

/// Why a frame is not a CANopen message we understand.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CanopenDecodeError {
    #[error("extended (29-bit) id {0:#010x}: not a CANopen frame")]
    ExtendedId(u32),
    #[error("id {0:#05x} is not a CANopen message we use")]
    ForeignId(u32),
    #[error("{what} (id {id:#05x}) with {len} data bytes, expected {expected}")]
    Length { what: &'static str, id: u16, len: usize, expected: &'static str },
    #[error("unknown NMT command {0:#04x}")]
    NmtCommand(u8),
    #[error("NMT command addressed to node {0}, outside 0..=127")]
    NmtNode(u8),
    #[error("heartbeat of node {node} with unknown state {state:#04x}")]
    HeartbeatState { node: NodeId, state: u8 },
}

impl CanopenDecodeError {
    /// The frame belongs to another protocol on the bus (or a CANopen service we do not use),
    /// rather than being a broken CANopen message.
    pub fn is_foreign(&self) -> bool {
        matches!(self, CanopenDecodeError::ExtendedId(_) | CanopenDecodeError::ForeignId(_))
    }
}

fn length_error(what: &'static str, id: u16, len: usize, expected: &'static str) -> CanopenDecodeError {
    CanopenDecodeError::Length { what, id, len, expected }
}

impl CanopenMessage {
    /// The message `frame` carries. Total: any frame gives a message or an error.
    pub fn decode(frame: &CanFrame) -> Result<CanopenMessage, CanopenDecodeError> {
        if frame.extended {
            return Err(CanopenDecodeError::ExtendedId(frame.id));
        }
        if frame.id > STANDARD_ID_MAX {
            return Err(CanopenDecodeError::ForeignId(frame.id));
        }
        let id = frame.id as u16;
        let data = frame.data();
        if id == NMT_ID {
            return decode_nmt(data);
        }
        if id == SYNC_ID {
            return match *data {
                [] => Ok(CanopenMessage::Sync { counter: None }),
                [counter] => Ok(CanopenMessage::Sync { counter: Some(counter) }),
                _ => Err(length_error("SYNC", id, data.len(), "0 or 1")),
            };
        }
        let function = id & FUNCTION_MASK;
        let Some(node) = NodeId::new((id & NODE_MASK) as u8) else {
            return Err(CanopenDecodeError::ForeignId(frame.id));
        };
        if let Some(number) = pdo_number(&TPDO_BASE, function) {
            let data = PdoData::new(data).ok_or_else(|| length_error("TPDO", id, data.len(), "0..=8"))?;
            return Ok(CanopenMessage::Tpdo { node, number, data });
        }
        if let Some(number) = pdo_number(&RPDO_BASE, function) {
            let data = PdoData::new(data).ok_or_else(|| length_error("RPDO", id, data.len(), "0..=8"))?;
            return Ok(CanopenMessage::Rpdo { node, number, data });
        }
        match function {
            EMCY_BASE => {
                let &[c0, c1, register, m0, m1, m2, m3, m4] = data else {
                    return Err(length_error("EMCY", id, data.len(), "8"));
                };
                let emergency = Emergency {
                    error_code: u16::from_le_bytes([c0, c1]),
                    error_register: register,
                    manufacturer: [m0, m1, m2, m3, m4],
                };
                Ok(CanopenMessage::Emergency { node, emergency })
            }
            SDO_REQUEST_BASE => {
                let bytes = sdo_bytes(id, data)?;
                Ok(CanopenMessage::SdoRequest { node, request: decode_sdo_request(bytes) })
            }
            SDO_RESPONSE_BASE => {
                let bytes = sdo_bytes(id, data)?;
                Ok(CanopenMessage::SdoResponse { node, response: decode_sdo_response(bytes) })
            }
            HEARTBEAT_BASE => {
                let &[byte] = data else {
                    return Err(length_error("heartbeat", id, data.len(), "1"));
                };
                let state =
                    NmtState::from_byte(byte).ok_or(CanopenDecodeError::HeartbeatState { node, state: byte })?;
                Ok(CanopenMessage::Heartbeat { node, state })
            }
            _ => Err(CanopenDecodeError::ForeignId(frame.id)),
        }
    }

    /// The 11-bit id this message is sent under.
    pub fn cob_id(&self) -> u16 {
        match *self {
            CanopenMessage::Nmt { .. } => NMT_ID,
            CanopenMessage::Sync { .. } => SYNC_ID,
            CanopenMessage::Emergency { node, .. } => EMCY_BASE + u16::from(node.get()),
            CanopenMessage::Tpdo { node, number, .. } => TPDO_BASE[number.index()] + u16::from(node.get()),
            CanopenMessage::Rpdo { node, number, .. } => RPDO_BASE[number.index()] + u16::from(node.get()),
            CanopenMessage::SdoRequest { node, .. } => SDO_REQUEST_BASE + u16::from(node.get()),
            CanopenMessage::SdoResponse { node, .. } => SDO_RESPONSE_BASE + u16::from(node.get()),
            CanopenMessage::Heartbeat { node, .. } => HEARTBEAT_BASE + u16::from(node.get()),
        }
    }

    /// The frame carrying this message (standard id, at most 8 data bytes).
    pub fn encode(&self) -> CanFrame {
        let mut frame = CanFrame { id: u32::from(self.cob_id()), len: 0, data: [0; 64], extended: false };
        let mut put = |bytes: &[u8]| {
            frame.data[..bytes.len()].copy_from_slice(bytes);
            frame.len = bytes.len() as u8;
        };
        match *self {
            CanopenMessage::Nmt { command, target } => {
                let node = match target {
                    NmtTarget::All => 0,
                    NmtTarget::Node(node) => node.get(),
                };
                put(&[command.byte(), node]);
            }
            CanopenMessage::Sync { counter: None } => put(&[]),
            CanopenMessage::Sync { counter: Some(counter) } => put(&[counter]),
            CanopenMessage::Emergency { emergency, .. } => {
                let [c0, c1] = emergency.error_code.to_le_bytes();
                let [m0, m1, m2, m3, m4] = emergency.manufacturer;
                put(&[c0, c1, emergency.error_register, m0, m1, m2, m3, m4]);
            }
            CanopenMessage::Tpdo { data, .. } | CanopenMessage::Rpdo { data, .. } => put(data.as_slice()),
            CanopenMessage::SdoRequest { request, .. } => put(&encode_sdo_request(&request)),
            CanopenMessage::SdoResponse { response, .. } => put(&encode_sdo_response(&response)),
            CanopenMessage::Heartbeat { state, .. } => put(&[state.byte()]),
        }
        frame
    }
}

fn decode_nmt(data: &[u8]) -> Result<CanopenMessage, CanopenDecodeError> {
    let &[command, node] = data else {
        return Err(length_error("NMT", NMT_ID, data.len(), "2"));
    };
    let command = NmtCommand::from_byte(command).ok_or(CanopenDecodeError::NmtCommand(command))?;
    let target = match node {
        0 => NmtTarget::All,
        node => NmtTarget::Node(NodeId::new(node).ok_or(CanopenDecodeError::NmtNode(node))?),
    };
    Ok(CanopenMessage::Nmt { command, target })
}

fn pdo_number(bases: &[u16; 4], function: u16) -> Option<PdoNumber> {
    PdoNumber::ALL.into_iter().find(|number| bases[number.index()] == function)
}

fn sdo_bytes(id: u16, data: &[u8]) -> Result<[u8; SDO_FRAME_LEN], CanopenDecodeError> {
    <[u8; SDO_FRAME_LEN]>::try_from(data).map_err(|_| length_error("SDO", id, data.len(), "8"))
}

/// Command byte, index, sub-index and the 4 data bytes of an SDO frame.
fn sdo_fields(bytes: [u8; SDO_FRAME_LEN]) -> (u8, u16, u8, [u8; 4]) {
    let [command, i0, i1, subindex, d0, d1, d2, d3] = bytes;
    (command, u16::from_le_bytes([i0, i1]), subindex, [d0, d1, d2, d3])
}

fn sdo_frame(command: u8, index: u16, subindex: u8, data: [u8; 4]) -> [u8; SDO_FRAME_LEN] {
    let [i0, i1] = index.to_le_bytes();
    let [d0, d1, d2, d3] = data;
    [command, i0, i1, subindex, d0, d1, d2, d3]
}

/// The data of an expedited initiate frame, `None` if the frame is not expedited.
fn expedited_data(command: u8, data: [u8; 4]) -> Option<SdoData> {
    if command & SDO_EXPEDITED == 0 {
        return None;
    }
    // Without the size bit the size is unspecified: all four bytes are the value.
    let len = if command & SDO_SIZE_INDICATED != 0 { 4 - usize::from((command >> 2) & 0x3) } else { 4 };
    SdoData::new(data.get(..len)?)
}

fn expedited_command(specifier: u8, data: &SdoData) -> u8 {
    let unused = 4 - data.as_slice().len() as u8;
    (specifier << 5) | (unused << 2) | SDO_EXPEDITED | SDO_SIZE_INDICATED
}

fn decode_sdo_request(bytes: [u8; SDO_FRAME_LEN]) -> SdoRequest {
    let (command, index, subindex, data) = sdo_fields(bytes);
    match command >> 5 {
        SDO_CCS_UPLOAD => SdoRequest::Upload { index, subindex },
        SDO_CCS_DOWNLOAD => match expedited_data(command, data) {
            Some(data) => SdoRequest::Download { index, subindex, data },
            None => SdoRequest::Unsupported(bytes),
        },
        SDO_CS_ABORT => SdoRequest::Abort { index, subindex, code: u32::from_le_bytes(data) },
        _ => SdoRequest::Unsupported(bytes),
    }
}

fn decode_sdo_response(bytes: [u8; SDO_FRAME_LEN]) -> SdoResponse {
    let (command, index, subindex, data) = sdo_fields(bytes);
    match command >> 5 {
        SDO_SCS_UPLOAD => match expedited_data(command, data) {
            Some(data) => SdoResponse::Upload { index, subindex, data },
            None => SdoResponse::Unsupported(bytes),
        },
        SDO_SCS_DOWNLOAD => SdoResponse::DownloadAck { index, subindex },
        SDO_CS_ABORT => SdoResponse::Abort { index, subindex, code: u32::from_le_bytes(data) },
        _ => SdoResponse::Unsupported(bytes),
    }
}

fn padded(data: &SdoData) -> [u8; 4] {
    let mut bytes = [0; 4];
    bytes[..data.as_slice().len()].copy_from_slice(data.as_slice());
    bytes
}

fn encode_sdo_request(request: &SdoRequest) -> [u8; SDO_FRAME_LEN] {
    match *request {
        SdoRequest::Upload { index, subindex } => sdo_frame(SDO_CCS_UPLOAD << 5, index, subindex, [0; 4]),
        SdoRequest::Download { index, subindex, data } => {
            sdo_frame(expedited_command(SDO_CCS_DOWNLOAD, &data), index, subindex, padded(&data))
        }
        SdoRequest::Abort { index, subindex, code } => {
            sdo_frame(SDO_CS_ABORT << 5, index, subindex, code.to_le_bytes())
        }
        SdoRequest::Unsupported(bytes) => bytes,
    }
}

fn encode_sdo_response(response: &SdoResponse) -> [u8; SDO_FRAME_LEN] {
    match *response {
        SdoResponse::Upload { index, subindex, data } => {
            sdo_frame(expedited_command(SDO_SCS_UPLOAD, &data), index, subindex, padded(&data))
        }
        SdoResponse::DownloadAck { index, subindex } => sdo_frame(SDO_SCS_DOWNLOAD << 5, index, subindex, [0; 4]),
        SdoResponse::Abort { index, subindex, code } => {
            sdo_frame(SDO_CS_ABORT << 5, index, subindex, code.to_le_bytes())
        }
        SdoResponse::Unsupported(bytes) => bytes,
    }
}
