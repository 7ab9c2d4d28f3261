//! MTData2 (MID 0x36): a sample as a sequence of packets `data id (u16 BE) | size (u8) | data`.
//!
//! The low nibble of a data id is its format: bits 0x3 the precision, bits 0xC the coordinate
//! frame. Unknown data ids are skipped by their size, as the protocol intends, so a device
//! configured with more outputs than we read still parses.

use nalgebra::Vector3;

/// An MTData2 data identifier, format bits included.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct DataId(pub u16);

impl DataId {
    /// u16 counter of the MTData2 messages sent.
    pub const PACKET_COUNTER: DataId = DataId(0x1020);
    /// u32 sample time in ticks of the device's 10 kHz clock.
    pub const SAMPLE_TIME_FINE: DataId = DataId(0x1060);
    /// Calibrated acceleration (specific force), m/s².
    pub const ACCELERATION: DataId = DataId(0x4020);
    /// Calibrated rate of turn, rad/s.
    pub const RATE_OF_TURN: DataId = DataId(0x8020);

    const FORMAT_MASK: u16 = 0x000F;
    const PRECISION_MASK: u16 = 0x0003;
    const FRAME_MASK: u16 = 0x000C;

    /// The data type without its format bits.
    pub fn kind(self) -> DataId {
        DataId(self.0 & !Self::FORMAT_MASK)
    }

    /// The format bits, `None` for the reserved frame bits 0xC.
    pub fn format(self) -> Option<DataFormat> {
        Some(DataFormat {
            precision: Precision::from_bits(self.0 & Self::PRECISION_MASK),
            frame: CoordinateFrame::from_bits(self.0 & Self::FRAME_MASK)?,
        })
    }

    /// This data type with `format`.
    pub fn with_format(self, format: DataFormat) -> DataId {
        DataId(self.kind().0 | format.precision.bits() | format.frame.bits())
    }
}

/// How each value of a vector output is encoded (big-endian in every case).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub enum Precision {
    /// IEEE 754 single.
    #[default]
    Float32,
    /// Signed fixed point, 12 integer and 20 fractional bits, in an i32.
    Fp1220,
    /// Signed fixed point, 16 integer and 32 fractional bits, sent as the 32-bit fraction
    /// followed by the 16-bit signed integer part (6 bytes).
    Fp1632,
    /// IEEE 754 double.
    Float64,
}

impl Precision {
    pub const ALL: [Precision; 4] = [Precision::Float32, Precision::Fp1220, Precision::Fp1632, Precision::Float64];

    fn from_bits(bits: u16) -> Precision {
        match bits & DataId::PRECISION_MASK {
            0 => Precision::Float32,
            1 => Precision::Fp1220,
            2 => Precision::Fp1632,
            _ => Precision::Float64,
        }
    }

    fn bits(self) -> u16 {
        match self {
            Precision::Float32 => 0,
            Precision::Fp1220 => 1,
            Precision::Fp1632 => 2,
            Precision::Float64 => 3,
        }
    }

    /// Bytes per value.
    pub fn value_bytes(self) -> usize {
        match self {
            Precision::Float32 | Precision::Fp1220 => 4,
            Precision::Fp1632 => 6,
            Precision::Float64 => 8,
        }
    }

    /// Appends `value`; fixed-point values saturate at the format's range and round to the
    /// nearest step (NaN becomes 0).
    pub fn encode(self, value: f64, out: &mut Vec<u8>) {
        match self {
            Precision::Float32 => out.extend_from_slice(&(value as f32).to_be_bytes()),
            Precision::Float64 => out.extend_from_slice(&value.to_be_bytes()),
            Precision::Fp1220 => out.extend_from_slice(&((value * FP1220_SCALE).round() as i32).to_be_bytes()),
            Precision::Fp1632 => {
                let raw = ((value * FP1632_SCALE).round() as i64).clamp(FP1632_MIN, FP1632_MAX);
                out.extend_from_slice(&(raw as u32).to_be_bytes());
                out.extend_from_slice(&((raw >> 32) as i16).to_be_bytes());
            }
        }
    }

    /// Decodes one value from exactly [`Self::value_bytes`] bytes (`None` for another length).
    pub fn decode(self, bytes: &[u8]) -> Option<f64> {
        Some(match self {
            Precision::Float32 => f64::from(f32::from_be_bytes(bytes.try_into().ok()?)),
            Precision::Float64 => f64::from_be_bytes(bytes.try_into().ok()?),
            Precision::Fp1220 => f64::from(i32::from_be_bytes(bytes.try_into().ok()?)) / FP1220_SCALE,
            Precision::Fp1632 => {
                let [f0, f1, f2, f3, i0, i1]: [u8; 6] = bytes.try_into().ok()?;
                let fraction = u32::from_be_bytes([f0, f1, f2, f3]);
                let integer = i16::from_be_bytes([i0, i1]);
                ((i64::from(integer) << 32) | i64::from(fraction)) as f64 / FP1632_SCALE
            }
        })
    }
}

const FP1220_SCALE: f64 = (1u64 << 20) as f64;
const FP1632_SCALE: f64 = (1u64 << 32) as f64;
const FP1632_MIN: i64 = -(1 << 47);
const FP1632_MAX: i64 = (1 << 47) - 1;

/// The coordinate convention of a vector output.
///
/// The protocol documentation (MT0101P rev. W) says the frame bits select the convention of
/// *orientation* outputs; acceleration and rate of turn are in the sensor frame. We still
/// honour them on vectors, as devices that apply them to all outputs do: with ENU (default) and
/// NWU the sensor frame is x forward, y left, z up, our body frame; with NED we take the vector
/// to be in x forward, y right, z down (the aerospace body frame that goes with NED) and rotate
/// it by 180° about x into the body frame, `(x, -y, -z)`. The emulator encodes the same way.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub enum CoordinateFrame {
    #[default]
    Enu,
    Ned,
    Nwu,
}

impl CoordinateFrame {
    pub const ALL: [CoordinateFrame; 3] = [CoordinateFrame::Enu, CoordinateFrame::Ned, CoordinateFrame::Nwu];

    fn from_bits(bits: u16) -> Option<CoordinateFrame> {
        match bits & DataId::FRAME_MASK {
            0x0 => Some(CoordinateFrame::Enu),
            0x4 => Some(CoordinateFrame::Ned),
            0x8 => Some(CoordinateFrame::Nwu),
            _ => None,
        }
    }

    fn bits(self) -> u16 {
        match self {
            CoordinateFrame::Enu => 0x0,
            CoordinateFrame::Ned => 0x4,
            CoordinateFrame::Nwu => 0x8,
        }
    }

    /// A vector output in this convention, expressed in the body frame.
    pub fn to_body(self, v: Vector3<f64>) -> Vector3<f64> {
        match self {
            CoordinateFrame::Enu | CoordinateFrame::Nwu => v,
            CoordinateFrame::Ned => Vector3::new(v.x, -v.y, -v.z),
        }
    }

    /// A body-frame vector in this convention (the rotation is its own inverse).
    pub fn from_body(self, v_body: Vector3<f64>) -> Vector3<f64> {
        self.to_body(v_body)
    }
}

/// Precision and coordinate frame of a vector output.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct DataFormat {
    pub precision: Precision,
    pub frame: CoordinateFrame,
}

impl DataFormat {
    pub fn new(precision: Precision, frame: CoordinateFrame) -> Self {
        DataFormat { precision, frame }
    }
}

/// Why an MTData2 payload could not be parsed. A frame that passed its checksum and still fails
/// here comes from a device we do not understand, not from line noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MtData2Error {
    #[error("packet header at byte {offset} cut short")]
    TruncatedHeader { offset: usize },
    #[error("packet {data_id:#06x} at byte {offset} announces {size} bytes, {available} left")]
    Truncated { data_id: u16, offset: usize, size: usize, available: usize },
    #[error("packet {data_id:#06x} has {size} bytes, its format has {expected}")]
    BadSize { data_id: u16, size: usize, expected: usize },
    #[error("packet {data_id:#06x} uses the reserved coordinate frame bits")]
    BadFrame { data_id: u16 },
}

/// The outputs of one MTData2 message we understand; vectors in the body frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MtData {
    pub packet_counter: Option<u16>,
    /// Ticks of the device's 10 kHz clock; wraps at 2³².
    pub sample_time_fine: Option<u32>,
    /// Specific force in the body frame.
    pub accel_mps2: Option<Vector3<f64>>,
    /// Angular rate in the body frame.
    pub gyro_radps: Option<Vector3<f64>>,
    /// Format the acceleration had on the wire (or is to be sent in).
    pub accel_format: DataFormat,
    /// Format the rate of turn had on the wire (or is to be sent in).
    pub gyro_format: DataFormat,
}

/// Data id, size byte.
const PACKET_HEADER_BYTES: usize = 3;

impl MtData {
    /// Parses an MTData2 payload. Unknown data ids are skipped; a repeated one overrides.
    pub fn parse(payload: &[u8]) -> Result<MtData, MtData2Error> {
        let mut data = MtData::default();
        let mut offset = 0;
        while offset < payload.len() {
            let Some(&[id_hi, id_lo, size]) = payload.get(offset..offset + PACKET_HEADER_BYTES) else {
                return Err(MtData2Error::TruncatedHeader { offset });
            };
            let id = DataId(u16::from_be_bytes([id_hi, id_lo]));
            let size = usize::from(size);
            let start = offset + PACKET_HEADER_BYTES;
            let Some(value) = payload.get(start..start + size) else {
                let available = payload.len() - start;
                return Err(MtData2Error::Truncated { data_id: id.0, offset, size, available });
            };
            match id {
                DataId::PACKET_COUNTER => data.packet_counter = Some(u16::from_be_bytes(exact(id, value)?)),
                DataId::SAMPLE_TIME_FINE => data.sample_time_fine = Some(u32::from_be_bytes(exact(id, value)?)),
                _ if id.kind() == DataId::ACCELERATION => {
                    let (v, format) = parse_vector(id, value)?;
                    data.accel_mps2 = Some(v);
                    data.accel_format = format;
                }
                _ if id.kind() == DataId::RATE_OF_TURN => {
                    let (v, format) = parse_vector(id, value)?;
                    data.gyro_radps = Some(v);
                    data.gyro_format = format;
                }
                _ => {}
            }
            offset = start + size;
        }
        Ok(data)
    }

    /// Appends the outputs present as an MTData2 payload, in the order of the documentation's
    /// example (counter, time, acceleration, rate of turn), each vector in its format.
    pub fn encode(&self, out: &mut Vec<u8>) {
        if let Some(counter) = self.packet_counter {
            put_packet(out, DataId::PACKET_COUNTER, &counter.to_be_bytes());
        }
        if let Some(ticks) = self.sample_time_fine {
            put_packet(out, DataId::SAMPLE_TIME_FINE, &ticks.to_be_bytes());
        }
        if let Some(accel) = self.accel_mps2 {
            put_vector(out, DataId::ACCELERATION, self.accel_format, accel);
        }
        if let Some(gyro) = self.gyro_radps {
            put_vector(out, DataId::RATE_OF_TURN, self.gyro_format, gyro);
        }
    }
}

fn exact<const N: usize>(id: DataId, value: &[u8]) -> Result<[u8; N], MtData2Error> {
    value.try_into().map_err(|_| MtData2Error::BadSize { data_id: id.0, size: value.len(), expected: N })
}

fn parse_vector(id: DataId, value: &[u8]) -> Result<(Vector3<f64>, DataFormat), MtData2Error> {
    let format = id.format().ok_or(MtData2Error::BadFrame { data_id: id.0 })?;
    let width = format.precision.value_bytes();
    if value.len() != 3 * width {
        return Err(MtData2Error::BadSize { data_id: id.0, size: value.len(), expected: 3 * width });
    }
    let mut xyz = [0.0; 3];
    for (out, bytes) in xyz.iter_mut().zip(value.chunks_exact(width)) {
        *out = format.precision.decode(bytes).unwrap_or_default();
    }
    Ok((format.frame.to_body(Vector3::from(xyz)), format))
}

fn put_packet(out: &mut Vec<u8>, id: DataId, value: &[u8]) {
    out.extend_from_slice(&id.0.to_be_bytes());
    out.push(value.len() as u8);
    out.extend_from_slice(value);
}

fn put_vector(out: &mut Vec<u8>, kind: DataId, format: DataFormat, v_body: Vector3<f64>) {
    let id = kind.with_format(format);
    out.extend_from_slice(&id.0.to_be_bytes());
    out.push((3 * format.precision.value_bytes()) as u8);
    for value in format.frame.from_body(v_body).iter() {
        format.precision.encode(*value, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_point_formats_decode_known_values() {
        // 12.20: 1.5 is 0x0018_0000; -1.0 is 0xFFF0_0000.
        assert_eq!(Precision::Fp1220.decode(&[0x00, 0x18, 0x00, 0x00]), Some(1.5));
        assert_eq!(Precision::Fp1220.decode(&[0xFF, 0xF0, 0x00, 0x00]), Some(-1.0));
        // 16.32: fraction first, then the signed integer part. -0.25 is -2^30, i.e. the 48-bit
        // value 0xFFFF_C000_0000: fraction 0xC000_0000, integer part 0xFFFF.
        assert_eq!(Precision::Fp1632.decode(&[0xC0, 0x00, 0x00, 0x00, 0xFF, 0xFF]), Some(-0.25));
        assert_eq!(Precision::Fp1632.decode(&[0x80, 0x00, 0x00, 0x00, 0x00, 0x03]), Some(3.5));
        assert_eq!(Precision::Fp1632.decode(&[0; 5]), None);
    }

    #[test]
    fn fixed_point_saturates_instead_of_wrapping() {
        let mut out = Vec::new();
        Precision::Fp1220.encode(1e9, &mut out);
        Precision::Fp1632.encode(-1e9, &mut out);
        assert_eq!(Precision::Fp1220.decode(&out[..4]), Some(f64::from(i32::MAX) / FP1220_SCALE));
        assert_eq!(Precision::Fp1632.decode(&out[4..]), Some(-32768.0));
    }

    #[test]
    fn reserved_frame_bits_and_bad_sizes_are_errors() {
        let bad_frame = [0x40, 0x2C, 12, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0];
        assert_eq!(MtData::parse(&bad_frame), Err(MtData2Error::BadFrame { data_id: 0x402C }));
        let bad_size = [0x10, 0x20, 3, 0, 0, 0];
        assert_eq!(MtData::parse(&bad_size), Err(MtData2Error::BadSize { data_id: 0x1020, size: 3, expected: 2 }));
        assert_eq!(MtData::parse(&[0x10, 0x20]), Err(MtData2Error::TruncatedHeader { offset: 0 }));
        assert!(matches!(MtData::parse(&[0x10, 0x20, 2, 0]), Err(MtData2Error::Truncated { available: 1, .. })));
    }
}
