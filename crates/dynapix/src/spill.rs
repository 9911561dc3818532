//! Maps of a pass kept on disk instead of in memory when the run has no cache folder: one
//! anonymous temporary file per map set (removed by the system when the last handle closes,
//! also when the process is killed), holding every frame's stored 16-bit map at a fixed
//! offset. What stays in memory is O(1) per frame (one presence flag), so the memory of an
//! offline run does not grow with the number of frames; the bytes read back are the bytes
//! written, so a run with a spill file tracks with the same weights as a run with a cache.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom, Write};
use std::sync::{Arc, Mutex};

use dynapix_io::Gray16Image;

use crate::error::{Error, Result};

/// Frame maps of one size in a temporary file, written and read from any thread.
#[derive(Clone)]
pub struct SpilledMaps {
    inner: Arc<Inner>,
}

struct Inner {
    /// The file, and which frames it holds.
    state: Mutex<State>,
    width: u32,
    height: u32,
}

struct State {
    file: File,
    present: Vec<bool>,
}

impl std::fmt::Debug for SpilledMaps {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "SpilledMaps {{ {}x{}, frames: {} }}",
            self.inner.width,
            self.inner.height,
            self.frames()
        )
    }
}

/// Two handles are equal when they are the same file.
impl PartialEq for SpilledMaps {
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.inner, &other.inner)
    }
}

fn spill_error(e: std::io::Error) -> Error {
    Error::Input(format!(
        "the temporary file of the motion maps ({}): {e}",
        std::env::temp_dir().display()
    ))
}

impl SpilledMaps {
    /// An empty set of `frames` maps of `width`×`height` in a new temporary file (in
    /// [`std::env::temp_dir`], i.e. `$TMPDIR`).
    pub fn new(frames: usize, width: u32, height: u32) -> Result<Self> {
        let file = tempfile::tempfile().map_err(spill_error)?;
        Ok(Self {
            inner: Arc::new(Inner {
                state: Mutex::new(State {
                    file,
                    present: vec![false; frames],
                }),
                width,
                height,
            }),
        })
    }

    fn frame_bytes(&self) -> u64 {
        u64::from(self.inner.width) * u64::from(self.inner.height) * 2
    }

    fn state(&self) -> Result<std::sync::MutexGuard<'_, State>> {
        self.inner
            .state
            .lock()
            .map_err(|_| Error::Input("motion maps: a worker thread panicked".into()))
    }

    /// Writes the map of frame `i`.
    pub fn put(&self, i: usize, map: &Gray16Image) -> Result<()> {
        if map.dimensions() != (self.inner.width, self.inner.height) {
            return Err(Error::Input(format!(
                "motion map of frame {i}: {}x{}, not the {}x{} of the sequence",
                map.width(),
                map.height(),
                self.inner.width,
                self.inner.height
            )));
        }
        let bytes: Vec<u8> = map.as_raw().iter().flat_map(|v| v.to_le_bytes()).collect();
        let offset = i as u64 * self.frame_bytes();
        let mut s = self.state()?;
        if i >= s.present.len() {
            return Err(Error::Input(format!("motion maps: no frame {i}")));
        }
        s.file.seek(SeekFrom::Start(offset)).map_err(spill_error)?;
        s.file.write_all(&bytes).map_err(spill_error)?;
        s.present[i] = true;
        Ok(())
    }

    /// The map of frame `i`, `None` when none was written.
    pub fn get(&self, i: usize) -> Result<Option<Gray16Image>> {
        let mut bytes = vec![0u8; self.frame_bytes() as usize];
        {
            let mut s = self.state()?;
            if !s.present.get(i).copied().unwrap_or(false) {
                return Ok(None);
            }
            let offset = i as u64 * self.frame_bytes();
            s.file.seek(SeekFrom::Start(offset)).map_err(spill_error)?;
            s.file.read_exact(&mut bytes).map_err(spill_error)?;
        }
        let values: Vec<u16> = bytes
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect();
        Gray16Image::from_raw(self.inner.width, self.inner.height, values)
            .map(Some)
            .ok_or_else(|| Error::Input(format!("motion map of frame {i}: wrong size")))
    }

    /// Number of frames written.
    pub fn frames(&self) -> usize {
        self.state()
            .map_or(0, |s| s.present.iter().filter(|&&p| p).count())
    }

    /// Bytes this set holds in memory (the per-frame presence flags; the maps are on disk).
    pub fn bytes_in_memory(&self) -> usize {
        std::mem::size_of::<Inner>() + self.state().map_or(0, |s| s.present.capacity())
    }

    /// Bytes of the temporary file.
    pub fn bytes_on_disk(&self) -> u64 {
        self.state()
            .ok()
            .and_then(|s| s.file.metadata().ok())
            .map_or(0, |m| m.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_read_back_as_written_from_any_thread() {
        let (w, h, n) = (7u32, 5u32, 40usize);
        let spill = SpilledMaps::new(n, w, h).unwrap();
        let map = |i: usize| {
            Gray16Image::from_fn(w, h, |x, y| {
                image::Luma([(i as u16).wrapping_mul(997) ^ (x as u16 * 31 + y as u16)])
            })
        };
        use rayon::prelude::*;
        (0..n)
            .into_par_iter()
            .filter(|i| i % 3 != 1)
            .for_each(|i| spill.put(i, &map(i)).unwrap());
        for i in 0..n {
            let got = spill.get(i).unwrap();
            if i % 3 == 1 {
                assert!(got.is_none(), "frame {i}");
            } else {
                assert_eq!(got.unwrap(), map(i), "frame {i}");
            }
        }
        assert_eq!(spill.frames(), (0..n).filter(|i| i % 3 != 1).count());
        // Frame 39 is the last one written: the file ends with it.
        assert_eq!(spill.bytes_on_disk(), n as u64 * u64::from(w * h * 2));
        // A map of another size, or a frame beyond the set, is refused.
        assert!(spill.put(0, &Gray16Image::new(w + 1, h)).is_err());
        assert!(spill.put(n, &map(0)).is_err());
        assert!(spill.get(n).unwrap().is_none());
    }
}
