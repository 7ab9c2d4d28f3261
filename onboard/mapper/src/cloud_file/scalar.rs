//! Scalar field types shared by the PLY and PCD readers: their sizes and binary decoding.

/// One field's binary type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Endian {
    Little,
    Big,
}

impl Scalar {
    /// PLY type names, both the classic and the sized spelling.
    pub(super) fn from_ply(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// PCD's `TYPE` letter (I signed, U unsigned, F float) with its `SIZE` in bytes.
    pub(super) fn from_pcd(kind: &str, size: &str) -> Option<Scalar> {
        Some(match (kind, size) {
            ("I", "1") => Scalar::I8,
            ("U", "1") => Scalar::U8,
            ("I", "2") => Scalar::I16,
            ("U", "2") => Scalar::U16,
            ("I", "4") => Scalar::I32,
            ("U", "4") => Scalar::U32,
            ("I", "8") => Scalar::I64,
            ("U", "8") => Scalar::U64,
            ("F", "4") => Scalar::F32,
            ("F", "8") => Scalar::F64,
            _ => return None,
        })
    }

    pub(super) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::I64 | Scalar::U64 | Scalar::F64 => 8,
        }
    }

    /// Decodes the value at the start of `bytes`; `None` when `bytes` is too short.
    pub(super) fn decode(self, bytes: &[u8], endian: Endian) -> Option<f64> {
        fn take<const N: usize>(bytes: &[u8], endian: Endian) -> Option<[u8; N]> {
            let mut raw: [u8; N] = bytes.get(..N)?.try_into().ok()?;
            if endian == Endian::Big {
                raw.reverse();
            }
            Some(raw)
        }
        Some(match self {
            Scalar::I8 => f64::from(i8::from_le_bytes(take(bytes, endian)?)),
            Scalar::U8 => f64::from(u8::from_le_bytes(take(bytes, endian)?)),
            Scalar::I16 => f64::from(i16::from_le_bytes(take(bytes, endian)?)),
            Scalar::U16 => f64::from(u16::from_le_bytes(take(bytes, endian)?)),
            Scalar::I32 => f64::from(i32::from_le_bytes(take(bytes, endian)?)),
            Scalar::U32 => f64::from(u32::from_le_bytes(take(bytes, endian)?)),
            Scalar::I64 => i64::from_le_bytes(take(bytes, endian)?) as f64,
            Scalar::U64 => u64::from_le_bytes(take(bytes, endian)?) as f64,
            Scalar::F32 => f64::from(f32::from_le_bytes(take(bytes, endian)?)),
            Scalar::F64 => f64::from_le_bytes(take(bytes, endian)?),
        })
    }
}

/// Parses one ASCII number of a record (integers and floats alike; `nan`/`inf` as Rust spells
/// them, which the callers then drop as non-finite).
pub(super) fn parse_ascii(token: &str) -> Option<f64> {
    token.parse::<f64>().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_both_byte_orders_and_rejects_short_input() {
        let le = 1.5f32.to_le_bytes();
        let be = 1.5f32.to_be_bytes();
        assert_eq!(Scalar::F32.decode(&le, Endian::Little), Some(1.5));
        assert_eq!(Scalar::F32.decode(&be, Endian::Big), Some(1.5));
        assert_eq!(Scalar::I16.decode(&(-3i16).to_be_bytes(), Endian::Big), Some(-3.0));
        assert_eq!(Scalar::F64.decode(&[0; 7], Endian::Little), None);
    }
}
