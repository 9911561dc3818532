//! Test fixtures shared by the tests of the submodules.

use super::SEARCH_BORDER;
use super::patch::LevelCtx;
use crate::pairs;
use crate::plane::Plane;

/// One pyramid level of a textured pair with a smooth non-rigid motion, for the kernel
/// tests (8×8 patches, mean normalisation, OpenCV's step).
pub(super) struct TestLevel {
    a: Plane,
    ax: Plane,
    ay: Plane,
    bp: Plane,
}

impl TestLevel {
    pub(super) fn new(w: u32, h: u32) -> Self {
        let b = pairs::texture(w, h);
        let a = pairs::make_a(&b, &pairs::smooth_nonrigid(w, h, 3.0)).unwrap();
        let a = Plane::from_gray(&a);
        let (ax, ay) = a.sobel();
        let bp = Plane::from_gray(&b).padded(SEARCH_BORDER);
        Self { a, ax, ay, bp }
    }

    pub(super) fn ctx(&self) -> LevelCtx<'_> {
        LevelCtx {
            a: &self.a,
            ax: &self.ax,
            ay: &self.ay,
            bp: &self.bp,
            ps: 8,
            mean_norm: true,
            step: 0.125,
        }
    }
}
