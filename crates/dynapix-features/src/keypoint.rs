//! Keypoint and descriptor types shared by the ORB extractor, the matcher and the tracker.

/// An ORB keypoint, coordinates at pyramid level 0 (as ORB-SLAM2's `mvKeys`).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KeyPoint {
    /// Column, level-0 pixels.
    pub x: f32,
    /// Row, level-0 pixels.
    pub y: f32,
    /// Orientation in degrees, [0, 360).
    pub angle: f32,
    /// FAST response (higher is stronger).
    pub response: f32,
    /// Pyramid level the keypoint was detected at.
    pub octave: u8,
    /// Patch diameter at level 0 (31 · scale).
    pub size: f32,
}

/// A 256-bit binary descriptor (rBRIEF).
pub type Descriptor = [u8; 32];

/// Hamming distance between two descriptors.
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    let mut d = 0;
    for i in 0..4 {
        let x = u64::from_le_bytes(a[i * 8..i * 8 + 8].try_into().unwrap_or([0; 8]));
        let y = u64::from_le_bytes(b[i * 8..i * 8 + 8].try_into().unwrap_or([0; 8]));
        d += (x ^ y).count_ones();
    }
    d
}
