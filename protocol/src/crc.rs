//! The project's one CRC-32: CRC-32/ISO-HDLC (the Ethernet/zlib CRC: reflected polynomial
//! 0xEDB88320, initial and final XOR all ones), from the `crc` crate. Serial frames, submap
//! payloads, the mapper's journal, the filter's checkpoints, bus recordings and feed logs all use
//! it, so a value computed in one place checks in any other.

use crc::{CRC_32_ISO_HDLC, Crc, Digest, Table};

/// Slice-by-16 tables (16 KiB) make the CRC ~5x faster than byte-wise tables; a rover's compute
/// board has the memory, and the serial path is where CPU per byte matters most.
pub const CRC32: Crc<u32, Table<16>> = Crc::<u32, Table<16>>::new(&CRC_32_ISO_HDLC);

/// The CRC-32 of `bytes`.
pub fn crc32(bytes: &[u8]) -> u32 {
    CRC32.checksum(bytes)
}

/// A running CRC-32 over several pieces.
pub fn crc32_digest() -> Digest<'static, u32, Table<16>> {
    CRC32.digest()
}

#[cfg(test)]
mod tests {
    #[test]
    fn check_value_of_the_standard() {
        assert_eq!(super::crc32(b"123456789"), 0xCBF4_3926);
        let mut digest = super::crc32_digest();
        digest.update(b"1234");
        digest.update(b"56789");
        assert_eq!(digest.finalize(), 0xCBF4_3926);
    }
}
