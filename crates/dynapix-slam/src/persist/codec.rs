//! Little-endian primitives of the map payload: a growable writer and a bounds-checked reader.
//! The reader never indexes past its slice and never allocates more than the bytes left can
//! hold, so any byte string gives a value or a [`PersistError`], never a panic or an
//! oversized allocation.

use super::PersistError;

/// Appends little-endian values to a byte vector.
pub(super) struct Writer {
    pub(super) buf: Vec<u8>,
}

impl Writer {
    pub(super) fn new() -> Self {
        Self { buf: Vec::new() }
    }

    pub(super) fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    pub(super) fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    pub(super) fn u32(&mut self, v: u32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub(super) fn u64(&mut self, v: u64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub(super) fn f32(&mut self, v: f32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub(super) fn f64(&mut self, v: f64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub(super) fn bytes(&mut self, v: &[u8]) {
        self.buf.extend_from_slice(v);
    }

    /// A collection length. Lengths above `u32::MAX` cannot occur in a map that fits in
    /// memory with these element sizes; they saturate and decoding then reports corruption.
    pub(super) fn len(&mut self, n: usize) {
        self.u32(u32::try_from(n).unwrap_or(u32::MAX));
    }

    /// An optional dense index; `u32::MAX` stands for `None`.
    pub(super) fn opt_index(&mut self, v: Option<u32>) {
        self.u32(v.unwrap_or(u32::MAX));
    }

    pub(super) fn str(&mut self, s: &str) {
        self.len(s.len());
        self.bytes(s.as_bytes());
    }
}

/// Reads little-endian values from a byte slice.
pub(super) struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(super) fn new(data: &'a [u8]) -> Self {
        Self { data, pos: 0 }
    }

    pub(super) fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    pub(super) fn take(&mut self, n: usize) -> Result<&'a [u8], PersistError> {
        let end = self.pos.checked_add(n).ok_or(PersistError::Truncated)?;
        let s = self
            .data
            .get(self.pos..end)
            .ok_or(PersistError::Truncated)?;
        self.pos = end;
        Ok(s)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], PersistError> {
        let s = self.take(N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub(super) fn u8(&mut self) -> Result<u8, PersistError> {
        Ok(self.array::<1>()?[0])
    }

    pub(super) fn bool(&mut self, what: &str) -> Result<bool, PersistError> {
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            b => Err(PersistError::corrupt(format!("{what}: boolean byte {b}"))),
        }
    }

    pub(super) fn u32(&mut self) -> Result<u32, PersistError> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    pub(super) fn u64(&mut self) -> Result<u64, PersistError> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    pub(super) fn f32(&mut self) -> Result<f32, PersistError> {
        Ok(f32::from_le_bytes(self.array()?))
    }

    pub(super) fn f64(&mut self) -> Result<f64, PersistError> {
        Ok(f64::from_le_bytes(self.array()?))
    }

    pub(super) fn descriptor(&mut self) -> Result<[u8; 32], PersistError> {
        self.array()
    }

    /// A collection length whose elements take at least `min_elem_bytes` each: a length the
    /// remaining bytes cannot hold is a truncation, which also bounds every allocation by the
    /// input size.
    pub(super) fn len(&mut self, min_elem_bytes: usize) -> Result<usize, PersistError> {
        let n = self.u32()? as usize;
        if n.saturating_mul(min_elem_bytes.max(1)) > self.remaining() {
            return Err(PersistError::Truncated);
        }
        Ok(n)
    }

    pub(super) fn opt_index(&mut self) -> Result<Option<u32>, PersistError> {
        let v = self.u32()?;
        Ok((v != u32::MAX).then_some(v))
    }

    pub(super) fn str(&mut self, what: &str) -> Result<String, PersistError> {
        let n = self.len(1)?;
        let s = self.take(n)?;
        String::from_utf8(s.to_vec())
            .map_err(|_| PersistError::corrupt(format!("{what}: not UTF-8")))
    }

    /// Reads `n` elements with `f`.
    pub(super) fn vec<T>(
        &mut self,
        min_elem_bytes: usize,
        mut f: impl FnMut(&mut Self) -> Result<T, PersistError>,
    ) -> Result<Vec<T>, PersistError> {
        let n = self.len(min_elem_bytes)?;
        let mut v = Vec::with_capacity(n);
        for _ in 0..n {
            v.push(f(self)?);
        }
        Ok(v)
    }
}
