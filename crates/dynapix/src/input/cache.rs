//! The decoded-frame cache of one run: decoded frames kept in memory up to a byte budget
//! (`sequence.decoded_cache_mib`) and the FAST corners of their grey images, so that the
//! passes of a DynaPix run decode every frame once.
//!
//! The budget counts what the cache holds, measured from what it stores: the frames' pixels
//! as copied into its chunks, its index entries, and the corners' buffers at their capacity.
//! The frames are copied into chunks of [`CHUNK_BYTES`] of their own instead of one
//! allocation per image: a frame is kept until the run ends, while the run allocates and
//! frees images of the same sizes on every thread; copies kept between those in the
//! allocator's heaps can pin the freed memory around them (glibc keeps free memory inside a
//! heap, and the binary asks it to keep up to 1 GiB), memory that no budget counts.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use dynapix_io::DepthImage;
use dynapix_slam::orb::FastCorners;
use image::RgbImage;

/// Bytes of one chunk of kept pixels: twice the largest allocation that the `dynapix` binary
/// lets glibc serve from its heaps ([`crate::profile::HEAP_ALLOCATION_LIMIT`]), so that every
/// chunk is a mapping of its own, outside the heaps, whose untouched tail takes no memory and
/// which goes back to the kernel when the cache is emptied.
pub(crate) const CHUNK_BYTES: usize = 2 * crate::profile::HEAP_ALLOCATION_LIMIT;

/// The share of the budget the cache leaves unused: 1/`MARGIN` (16 MiB of the default
/// 1 GiB). It covers memory that keeping frames costs the process but that the cache cannot
/// count (allocator bookkeeping and heap fragmentation around the run's own images while the
/// cache is full), and the run-to-run variation of the rest of the process (its peak moved by
/// 2.7 MB between two runs of one 3,000-frame sequence), so that a run's peak memory stays
/// within its peak without a cache plus the budget (issue 36; the figures in BENCHMARKS.md).
pub(crate) const MARGIN: usize = 64;

/// Values appended into large chunks and only ever dropped all together.
struct Chunks<T> {
    chunks: Vec<Vec<T>>,
}

impl<T: Copy> Chunks<T> {
    fn new() -> Self {
        Self { chunks: Vec::new() }
    }

    /// Appends `v` (in a new chunk when the last one has no room); returns where it is.
    fn push(&mut self, v: &[T]) -> Span {
        let room = self
            .chunks
            .last()
            .is_some_and(|c| c.capacity() - c.len() >= v.len());
        if !room {
            let per_chunk = CHUNK_BYTES / std::mem::size_of::<T>().max(1);
            self.chunks.push(Vec::with_capacity(per_chunk.max(v.len())));
        }
        let chunk = self.chunks.len() - 1;
        let c = &mut self.chunks[chunk];
        let start = c.len();
        c.extend_from_slice(v);
        Span {
            chunk,
            start,
            len: v.len(),
        }
    }

    fn get(&self, s: Span) -> Option<&[T]> {
        self.chunks.get(s.chunk)?.get(s.start..s.start + s.len)
    }
}

/// Where a stored slice is.
#[derive(Clone, Copy, Debug)]
struct Span {
    chunk: usize,
    start: usize,
    len: usize,
}

/// A kept frame: its size and where its pixels are.
#[derive(Clone, Copy, Debug)]
struct Kept {
    width: u32,
    height: u32,
    rgb: Span,
    depth: Span,
}

/// The kept frames and the bytes charged to the budget (frames and corners).
struct Frames {
    used: usize,
    index: HashMap<usize, Kept>,
    rgb: Chunks<u8>,
    depth: Chunks<f32>,
}

impl Frames {
    fn new() -> Self {
        Self {
            used: 0,
            index: HashMap::new(),
            rgb: Chunks::new(),
            depth: Chunks::new(),
        }
    }

    /// Frame `i` copied out of the chunks.
    fn frame(&self, i: usize) -> Option<(RgbImage, DepthImage)> {
        let k = self.index.get(&i)?;
        let rgb = RgbImage::from_raw(k.width, k.height, self.rgb.get(k.rgb)?.to_vec())?;
        Some((rgb, self.depth(i)?))
    }

    /// The depth of frame `i` copied out of the chunks.
    fn depth(&self, i: usize) -> Option<DepthImage> {
        let k = self.index.get(&i)?;
        DepthImage::from_raw(k.width, k.height, self.depth.get(k.depth)?.to_vec())
    }
}

/// The bytes a kept frame adds: its pixels as stored and its index entry.
fn frame_bytes(rgb: &RgbImage, depth: &DepthImage) -> usize {
    std::mem::size_of_val(rgb.as_raw().as_slice())
        + std::mem::size_of_val(depth.as_raw().as_slice())
        + std::mem::size_of::<(usize, Kept)>()
}

/// The bytes kept corners add: their buffers ([`FastCorners::bytes`]), the `Arc`'s counters
/// and the index entry.
fn corner_bytes(c: &FastCorners) -> usize {
    c.bytes() + 2 * std::mem::size_of::<usize>() + std::mem::size_of::<(usize, Arc<FastCorners>)>()
}

/// Decoded frames kept in memory up to a byte budget, first read first kept.
#[derive(Clone)]
pub(crate) struct DecodedFrames {
    budget: usize,
    /// Off until a multi-pass run asks for it ([`super::Input::keep_decoded_frames`]).
    enabled: Arc<AtomicBool>,
    /// The frames kept and the bytes used.
    kept: Arc<Mutex<Frames>>,
    /// The FAST corners of the frames' grey images, by index (kept while `enabled`, counted
    /// in the budget).
    corners: Arc<Mutex<HashMap<usize, Arc<FastCorners>>>>,
    /// The most bytes kept at once since the cache was made.
    peak: Arc<AtomicUsize>,
}

impl std::fmt::Debug for DecodedFrames {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (used, n) = self
            .kept
            .lock()
            .map(|k| (k.used, k.index.len()))
            .unwrap_or((0, 0));
        write!(
            f,
            "DecodedFrames {{ budget: {}, used: {used}, frames: {n} }}",
            self.budget
        )
    }
}

impl DecodedFrames {
    /// An empty cache of `budget_mib` MiB, off.
    pub(crate) fn new(budget_mib: usize) -> Self {
        Self {
            budget: budget_mib.saturating_mul(1 << 20),
            enabled: Arc::new(AtomicBool::new(false)),
            kept: Arc::new(Mutex::new(Frames::new())),
            corners: Arc::new(Mutex::new(HashMap::new())),
            peak: Arc::new(AtomicUsize::new(0)),
        }
    }

    /// An empty cache with the same budget, off, shared with no one (the cache of one run).
    pub(crate) fn fresh(&self) -> Self {
        Self::new(0).with_budget(self.budget)
    }

    fn with_budget(mut self, budget: usize) -> Self {
        self.budget = budget;
        self
    }

    /// The bytes the cache may hold: the budget less its margin ([`MARGIN`]).
    fn limit(&self) -> usize {
        self.budget - self.budget / MARGIN
    }

    /// Takes `bytes` of the budget when they fit within [`Self::limit`] (the lock on the
    /// kept frames held).
    fn charge(&self, used: &mut usize, bytes: usize) -> bool {
        if *used + bytes > self.limit() {
            return false;
        }
        *used += bytes;
        self.peak.fetch_max(*used, Ordering::Relaxed);
        true
    }

    /// The most bytes of frames and corners kept at once since the cache was made.
    pub(crate) fn peak_bytes(&self) -> usize {
        self.peak.load(Ordering::Relaxed)
    }

    /// A copy of frame `i`, when kept.
    pub(crate) fn rgbd(&self, i: usize) -> Option<(RgbImage, DepthImage)> {
        self.kept.lock().ok()?.frame(i)
    }

    /// A copy of the depth of frame `i`, when kept.
    pub(crate) fn depth(&self, i: usize) -> Option<DepthImage> {
        self.kept.lock().ok()?.depth(i)
    }

    /// Keeps (a copy of) frame `i` when it fits the budget.
    pub(crate) fn offer(&self, i: usize, rgb: &RgbImage, depth: &DepthImage) {
        if !self.enabled.load(Ordering::Relaxed) {
            return;
        }
        let bytes = frame_bytes(rgb, depth);
        let Ok(mut k) = self.kept.lock() else { return };
        if k.index.contains_key(&i) || !self.charge(&mut k.used, bytes) {
            return;
        }
        let kept = Kept {
            width: rgb.width(),
            height: rgb.height(),
            rgb: k.rgb.push(rgb.as_raw()),
            depth: k.depth.push(depth.as_raw()),
        };
        k.index.insert(i, kept);
    }

    /// Starts (`true`) or stops keeping frames; stopping frees them.
    pub(crate) fn set_enabled(&self, on: bool) {
        self.enabled.store(on, Ordering::Relaxed);
        if !on && let Ok(mut k) = self.kept.lock() {
            *k = Frames::new();
        }
        if !on && let Ok(mut c) = self.corners.lock() {
            c.clear();
            c.shrink_to_fit();
        }
    }

    /// The FAST corners of frame `i`, when kept.
    pub(crate) fn corners(&self, i: usize) -> Option<Arc<FastCorners>> {
        self.corners.lock().ok()?.get(&i).cloned()
    }

    /// Keeps the FAST corners of frame `i` while frames are kept and they fit the budget
    /// (shared with the frames).
    pub(crate) fn keep_corners(&self, i: usize, corners: Arc<FastCorners>) {
        if !self.enabled.load(Ordering::Relaxed) {
            return;
        }
        let bytes = corner_bytes(&corners);
        let (Ok(mut k), Ok(mut c)) = (self.kept.lock(), self.corners.lock()) else {
            return;
        };
        if c.contains_key(&i) || !self.charge(&mut k.used, bytes) {
            return;
        }
        c.insert(i, corners);
    }

    /// Budget, peak bytes, and the bytes, frames, chunks, corner sets and their bytes kept now.
    pub(crate) fn record(&self) -> serde_json::Value {
        let (used, frames, chunks) = self.kept.lock().map_or((0, 0, 0), |k| {
            (
                k.used,
                k.index.len(),
                k.rgb.chunks.len() + k.depth.chunks.len(),
            )
        });
        let (sets, corner_bytes) = self.corners.lock().map_or((0, 0), |c| {
            (c.len(), c.values().map(|c| corner_bytes(c)).sum::<usize>())
        });
        serde_json::json!({
            "budget_bytes": self.budget,
            "peak_bytes": self.peak_bytes(),
            "bytes": used,
            "frames": frames,
            "chunks": chunks,
            "corner_sets": sets,
            "corner_bytes": corner_bytes,
        })
    }

    /// Number of frames kept.
    pub(crate) fn frames_kept(&self) -> usize {
        self.kept.lock().map_or(0, |k| k.index.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynapix_slam::orb::{OrbExtractor, OrbParams};

    fn frame(w: u32, h: u32, seed: u8) -> (RgbImage, DepthImage) {
        let rgb = RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 7 + y * 3) as u8, seed, 9]));
        let depth = DepthImage::from_fn(w, h, |x, y| {
            image::Luma([x as f32 * 0.01 + y as f32 + seed as f32])
        });
        (rgb, depth)
    }

    #[test]
    fn kept_frames_read_back_identical_and_the_budget_counts_what_is_stored() {
        let cache = DecodedFrames::new(1);
        cache.set_enabled(true);
        let frames: Vec<_> = (0..20).map(|s| frame(160, 120, s)).collect();
        for (i, (rgb, depth)) in frames.iter().enumerate() {
            cache.offer(i, rgb, depth);
        }
        let one = frame_bytes(&frames[0].0, &frames[0].1);
        // The pixels and the index entry, not only the pixels.
        assert!(one > 160 * 120 * (3 + 4));
        let n = cache.frames_kept();
        // The budget less its margin: 1 MiB − 16 KiB.
        assert_eq!(n, ((1 << 20) - (1 << 20) / MARGIN) / one);
        assert_eq!(cache.record()["bytes"], n * one);
        for (i, f) in frames.iter().enumerate().take(n) {
            assert!(cache.rgbd(i).as_ref() == Some(f), "frame {i}");
            assert!(cache.depth(i).as_ref() == Some(&f.1), "depth {i}");
        }
        assert!(cache.rgbd(n).is_none() && cache.depth(n).is_none());
        // Corners are charged at the capacity of their buffers, within the same budget.
        let orb = OrbExtractor::new(OrbParams::default()).unwrap();
        let gray = image::GrayImage::from_fn(160, 120, |x, y| {
            image::Luma([((x / 8 + y / 8) % 2 * 200) as u8])
        });
        let corners = orb.detect_corners(&gray);
        assert!(corners.len() > 10);
        assert!(corners.bytes() >= corners.len() * std::mem::size_of::<[f32; 3]>());
        cache.keep_corners(0, corners.clone());
        assert_eq!(cache.record()["bytes"], n * one + corner_bytes(&corners));
        assert!(cache.peak_bytes() <= (1 << 20) - (1 << 20) / MARGIN);
        cache.set_enabled(false);
        assert_eq!(cache.frames_kept(), 0);
        assert_eq!(cache.record()["bytes"], 0);
        assert!(cache.corners(0).is_none());
    }

    #[test]
    fn chunks_hold_slices_in_order_and_start_a_new_chunk_when_full() {
        let mut c: Chunks<u8> = Chunks::new();
        let a = c.push(&[1, 2, 3]);
        let b = c.push(&[4, 5]);
        assert_eq!((a.chunk, b.chunk, b.start), (0, 0, 3));
        assert_eq!(c.get(b), Some(&[4u8, 5][..]));
        let big = vec![7u8; CHUNK_BYTES];
        let s = c.push(&big);
        assert_eq!((s.chunk, s.start), (1, 0));
        assert_eq!(c.get(s).map(<[u8]>::len), Some(CHUNK_BYTES));
        assert_eq!(c.get(a), Some(&[1u8, 2, 3][..]));
    }
}
