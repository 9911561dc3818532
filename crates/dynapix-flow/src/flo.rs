//! Middlebury `.flo` optical-flow files (Baker et al., "A Database and Evaluation Methodology
//! for Optical Flow"): the float 202021.25 ("PIEH"), width and height as 32-bit integers, then
//! `width·height` pairs (u, v) of 32-bit floats, row-major, all little-endian.

use crate::{FlowError, FlowField};
use std::path::Path;

/// The magic number of `.flo` files.
pub const FLO_MAGIC: f32 = 202021.25;
/// Largest accepted side, to reject garbage headers before allocating.
const MAX_SIDE: u32 = 1 << 16;

/// Parses `.flo` bytes; `path` only names the source in errors.
pub fn parse_flo(bytes: &[u8], path: &Path) -> Result<FlowField, FlowError> {
    let bad = |reason: String| FlowError::BadFile {
        path: path.to_path_buf(),
        reason,
    };
    let word = |i: usize| -> Option<[u8; 4]> { bytes.get(4 * i..4 * i + 4)?.try_into().ok() };
    let header = (word(0), word(1), word(2));
    let (Some(m), Some(wb), Some(hb)) = header else {
        return Err(bad(format!(
            "too short for a .flo header: {} bytes, need 12",
            bytes.len()
        )));
    };
    let magic = f32::from_le_bytes(m);
    if magic != FLO_MAGIC {
        return Err(bad(format!(
            "not a .flo file: magic {magic} (expected {FLO_MAGIC})"
        )));
    }
    let (w, h) = (i32::from_le_bytes(wb), i32::from_le_bytes(hb));
    if w < 0 || h < 0 || w as u32 > MAX_SIDE || h as u32 > MAX_SIDE {
        return Err(bad(format!("implausible size {w} x {h}")));
    }
    let n = w as usize * h as usize;
    let expected = 12 + 8 * n;
    if bytes.len() != expected {
        return Err(bad(format!(
            "size {w} x {h} needs {expected} bytes, file has {}",
            bytes.len()
        )));
    }
    let data = bytes[12..]
        .chunks_exact(8)
        .map(|c| {
            let u = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
            let v = f32::from_le_bytes([c[4], c[5], c[6], c[7]]);
            [u, v]
        })
        .collect();
    Ok(FlowField {
        width: w as u32,
        height: h as u32,
        data,
    })
}

/// Reads a `.flo` file.
pub fn read_flo(path: impl AsRef<Path>) -> Result<FlowField, FlowError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| FlowError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_flo(&bytes, path)
}

/// Encodes a flow as `.flo` bytes.
pub fn encode_flo(flow: &FlowField) -> Vec<u8> {
    let mut out = Vec::with_capacity(12 + 8 * flow.data.len());
    out.extend_from_slice(&FLO_MAGIC.to_le_bytes());
    out.extend_from_slice(&(flow.width as i32).to_le_bytes());
    out.extend_from_slice(&(flow.height as i32).to_le_bytes());
    for f in &flow.data {
        out.extend_from_slice(&f[0].to_le_bytes());
        out.extend_from_slice(&f[1].to_le_bytes());
    }
    out
}

/// Writes a `.flo` file atomically ([`dynapix_io::write_atomic`]).
pub fn write_flo(path: impl AsRef<Path>, flow: &FlowField) -> Result<(), FlowError> {
    let path = path.as_ref();
    if flow.data.len() != flow.width as usize * flow.height as usize {
        return Err(FlowError::BadFile {
            path: path.to_path_buf(),
            reason: format!(
                "flow has {} vectors but size {} x {}",
                flow.data.len(),
                flow.width,
                flow.height
            ),
        });
    }
    dynapix_io::write_atomic(path, &encode_flo(flow))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]

        /// Arbitrary bytes, bare or behind a valid magic and size, are a flow or an error
        /// naming the file, never a panic.
        #[test]
        fn parse_never_panics(
            bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..120),
            w in -2i32..6,
            h in -2i32..6,
            with_header in proptest::prelude::any::<bool>(),
        ) {
            let mut data = Vec::new();
            if with_header {
                data.extend_from_slice(&FLO_MAGIC.to_le_bytes());
                data.extend_from_slice(&w.to_le_bytes());
                data.extend_from_slice(&h.to_le_bytes());
            }
            data.extend_from_slice(&bytes);
            if let Err(e) = parse_flo(&data, Path::new("x.flo")) {
                proptest::prop_assert!(e.to_string().contains("x.flo"), "{}", e);
            }
        }
    }

    fn sample() -> FlowField {
        let mut f = FlowField::zeros(5, 3);
        for (i, d) in f.data.iter_mut().enumerate() {
            *d = [i as f32 * 0.5 - 2.0, -(i as f32) * 1.25];
        }
        f
    }

    #[test]
    fn round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.flo");
        let f = sample();
        write_flo(&p, &f).unwrap();
        assert_eq!(std::fs::metadata(&p).unwrap().len(), 12 + 8 * 15);
        assert_eq!(read_flo(&p).unwrap(), f);
        assert!(!dir.path().join("a.flo.tmp").exists());
    }

    #[test]
    fn errors_name_the_file_and_the_problem() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing.flo");
        let e = read_flo(&missing).unwrap_err().to_string();
        assert!(e.contains("missing.flo"), "{e}");

        let bad_magic = dir.path().join("magic.flo");
        let mut bytes = encode_flo(&sample());
        bytes[0] ^= 0xff;
        std::fs::write(&bad_magic, &bytes).unwrap();
        let e = read_flo(&bad_magic).unwrap_err().to_string();
        assert!(e.contains("magic.flo") && e.contains("magic"), "{e}");

        let truncated = dir.path().join("short.flo");
        let bytes = encode_flo(&sample());
        std::fs::write(&truncated, &bytes[..bytes.len() - 4]).unwrap();
        let e = read_flo(&truncated).unwrap_err().to_string();
        assert!(e.contains("short.flo") && e.contains("bytes"), "{e}");

        let tiny = dir.path().join("tiny.flo");
        std::fs::write(&tiny, [1u8, 2, 3]).unwrap();
        assert!(read_flo(&tiny).unwrap_err().to_string().contains("header"));

        let mut neg = encode_flo(&sample());
        neg[4..8].copy_from_slice(&(-5i32).to_le_bytes());
        let e = parse_flo(&neg, Path::new("neg.flo"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("implausible"), "{e}");
    }
}
