//! Little-endian byte reading that fails instead of panicking, for the decoders.

use super::ExchangeError;

pub(crate) struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(data: &'a [u8]) -> Reader<'a> {
        Reader { data, pos: 0 }
    }

    pub(crate) fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    pub(crate) fn bytes(&mut self, n: usize) -> Result<&'a [u8], ExchangeError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len()).ok_or(ExchangeError::Truncated)?;
        let slice = &self.data[self.pos..end];
        self.pos = end;
        Ok(slice)
    }

    pub(crate) fn rest(&mut self) -> &'a [u8] {
        let slice = &self.data[self.pos..];
        self.pos = self.data.len();
        slice
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], ExchangeError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.bytes(N)?);
        Ok(a)
    }

    pub(crate) fn u8(&mut self) -> Result<u8, ExchangeError> {
        Ok(self.array::<1>()?[0])
    }

    pub(crate) fn u16(&mut self) -> Result<u16, ExchangeError> {
        Ok(u16::from_le_bytes(self.array()?))
    }

    pub(crate) fn u32(&mut self) -> Result<u32, ExchangeError> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    pub(crate) fn i32(&mut self) -> Result<i32, ExchangeError> {
        Ok(i32::from_le_bytes(self.array()?))
    }

    pub(crate) fn u64(&mut self) -> Result<u64, ExchangeError> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    pub(crate) fn f32(&mut self) -> Result<f32, ExchangeError> {
        Ok(f32::from_le_bytes(self.array()?))
    }

    /// A finite f64 (every float in the format is a measurement or a pose: NaN means corruption).
    pub(crate) fn f64(&mut self) -> Result<f64, ExchangeError> {
        let v = f64::from_le_bytes(self.array()?);
        if v.is_finite() { Ok(v) } else { Err(ExchangeError::NonFinite) }
    }
}
