//! A stable 64-bit FNV-1a hash for cache keys and content fingerprints. Unlike the standard
//! library's hasher it is specified, so a key written by one build is valid in the next.

/// FNV-1a, 64 bits.
#[derive(Clone, Copy, Debug)]
pub struct Fnv64(u64);

impl Default for Fnv64 {
    fn default() -> Self {
        Self::new()
    }
}

impl Fnv64 {
    /// A fresh hasher.
    pub fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }

    /// Feeds bytes.
    pub fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        // A length marker, so ("ab", "c") and ("a", "bc") differ.
        for b in (bytes.len() as u64).to_le_bytes() {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }

    /// The hash as 16 hex digits.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }

    /// The hash of one byte string, as hex.
    pub fn of(bytes: &[u8]) -> String {
        let mut h = Self::new();
        h.write(bytes);
        h.hex()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stable_and_sensitive() {
        assert_eq!(Fnv64::of(b"dynapix"), Fnv64::of(b"dynapix"));
        assert_ne!(Fnv64::of(b"dynapix"), Fnv64::of(b"dynapiX"));
        let mut a = Fnv64::new();
        a.write(b"ab");
        a.write(b"c");
        let mut b = Fnv64::new();
        b.write(b"a");
        b.write(b"bc");
        assert_ne!(a.hex(), b.hex());
        // Fixed value: a change of the function would invalidate every cache.
        assert_eq!(Fnv64::of(b""), "a8c7f832281a39c5");
    }
}
