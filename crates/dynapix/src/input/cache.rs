//! The decoded-frame cache of one run: decoded frames kept in memory up to a byte budget
//! (`sequence.decoded_cache_mib`) and the FAST corners of their grey images, so that the
//! passes of a DynaPix run decode every frame once.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use dynapix_slam::orb::FastCorners;
use image::RgbImage;

/// One decoded frame: colour image and depth (metres).
type DecodedFrame = Arc<(RgbImage, dynapix_io::DepthImage)>;

/// Decoded frames kept in memory up to a byte budget, first read first kept.
#[derive(Clone)]
pub(crate) struct DecodedFrames {
    budget: usize,
    /// Off until a multi-pass run asks for it ([`super::Input::keep_decoded_frames`]).
    enabled: Arc<std::sync::atomic::AtomicBool>,
    /// Bytes used and the frames kept, by index.
    kept: Arc<Mutex<(usize, HashMap<usize, DecodedFrame>)>>,
    /// The FAST corners of the frames' grey images, by index (kept while `enabled`, a few
    /// tens of kilobytes per frame counted in the budget).
    corners: Arc<Mutex<HashMap<usize, Arc<FastCorners>>>>,
    /// The most bytes kept at once since the cache was made.
    peak: Arc<std::sync::atomic::AtomicUsize>,
}

impl std::fmt::Debug for DecodedFrames {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (used, n) = self.kept.lock().map(|k| (k.0, k.1.len())).unwrap_or((0, 0));
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
            enabled: Arc::new(std::sync::atomic::AtomicBool::new(false)),
            kept: Arc::new(Mutex::new((0, HashMap::new()))),
            corners: Arc::new(Mutex::new(HashMap::new())),
            peak: Arc::new(std::sync::atomic::AtomicUsize::new(0)),
        }
    }

    /// An empty cache with the same budget, off, shared with no one (the cache of one run).
    pub(crate) fn fresh(&self) -> Self {
        Self {
            budget: self.budget,
            enabled: Arc::new(std::sync::atomic::AtomicBool::new(false)),
            kept: Arc::new(Mutex::new((0, HashMap::new()))),
            corners: Arc::new(Mutex::new(HashMap::new())),
            peak: Arc::new(std::sync::atomic::AtomicUsize::new(0)),
        }
    }

    /// Takes `bytes` of the budget when they fit (the lock on the kept frames held).
    fn charge(&self, used: &mut usize, bytes: usize) -> bool {
        if *used + bytes > self.budget {
            return false;
        }
        *used += bytes;
        self.peak
            .fetch_max(*used, std::sync::atomic::Ordering::Relaxed);
        true
    }

    /// The most bytes of frames and corners kept at once since the cache was made.
    pub(crate) fn peak_bytes(&self) -> usize {
        self.peak.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Frame `i`, when kept.
    pub(crate) fn get(&self, i: usize) -> Option<DecodedFrame> {
        self.kept.lock().ok()?.1.get(&i).cloned()
    }

    /// Keeps frame `i` when it fits the budget.
    pub(crate) fn offer(&self, i: usize, rgb: &RgbImage, depth: &dynapix_io::DepthImage) {
        if !self.enabled.load(std::sync::atomic::Ordering::Relaxed) {
            return;
        }
        let bytes = rgb.as_raw().len() + std::mem::size_of_val(depth.as_raw().as_slice());
        let Ok(mut k) = self.kept.lock() else { return };
        if k.1.contains_key(&i) || !self.charge(&mut k.0, bytes) {
            return;
        }
        k.1.insert(i, Arc::new((rgb.clone(), depth.clone())));
    }

    /// Starts (`true`) or stops keeping frames; stopping frees them.
    pub(crate) fn set_enabled(&self, on: bool) {
        self.enabled.store(on, std::sync::atomic::Ordering::Relaxed);
        if !on && let Ok(mut k) = self.kept.lock() {
            *k = (0, HashMap::new());
        }
        if !on && let Ok(mut c) = self.corners.lock() {
            c.clear();
        }
    }

    /// The FAST corners of frame `i`, when kept.
    pub(crate) fn corners(&self, i: usize) -> Option<Arc<FastCorners>> {
        self.corners.lock().ok()?.get(&i).cloned()
    }

    /// Keeps the FAST corners of frame `i` while frames are kept and they fit the budget
    /// (shared with the frames).
    pub(crate) fn keep_corners(&self, i: usize, corners: Arc<FastCorners>) {
        if !self.enabled.load(std::sync::atomic::Ordering::Relaxed) {
            return;
        }
        // Three f32 (x, y, response) per corner.
        let bytes = corners.len() * std::mem::size_of::<[f32; 3]>();
        let (Ok(mut k), Ok(mut c)) = (self.kept.lock(), self.corners.lock()) else {
            return;
        };
        if c.contains_key(&i) || !self.charge(&mut k.0, bytes) {
            return;
        }
        c.insert(i, corners);
    }

    /// Number of frames kept.
    pub(crate) fn frames_kept(&self) -> usize {
        self.kept.lock().map_or(0, |k| k.1.len())
    }
}
