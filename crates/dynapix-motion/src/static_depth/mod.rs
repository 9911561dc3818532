//! Static depth and the geometric cue (new in this project; not in the paper).
//!
//! Movers are in front of the static scene: a pixel whose depth is clearly nearer than the
//! static surface seen at the same place from other times is not static. The static depth of
//! the current view is built from the depth maps of many frames over a wide time window
//! (seconds, past and future), each forward-splatted into the current view with its relative
//! pose (nearest surface per pixel). Per pixel, the static surface is the farthest depth that
//! at least `min_support` views agree on (movers occlude the static scene, so they are nearer;
//! a single far outlier is not trusted), refined to the median of the views that agree with it.
//! Because the window spans seconds, the scene behind a person who stays in one place for a
//! moment is still recovered from the frames before they arrived or after they left.
//!
//! The cue is the paper's movable term (difference from a static background, §3.1) computed
//! on depth instead of colour, so it covers whole bodies instead of textured edges. It is
//! evaluated at a working resolution of about [`StaticDepthParams::working_width`] pixels
//! across, so its pixel constants mean the same at every input resolution.
//!
//! Everything here is pure computation; which frames and poses to use is the caller's choice.

mod depth;
#[cfg(test)]
mod fixtures;
mod geometric;
mod network;
mod params;
mod splat;
mod support;

pub use depth::{StaticDepthWorkspace, select_views, static_depth, static_depth_with};
pub use geometric::{geometric_frame, geometric_frame_with, geometric_term};
pub use params::StaticDepthParams;

use dynapix_geometry::se3::Se3;
use image::Luma;

use crate::FloatImage;

/// A depth map subsampled to the working resolution: pixel `(i, j)` holds the depth of input
/// pixel `(i·factor, j·factor)` (no averaging across depth edges).
#[derive(Clone, Debug, PartialEq)]
pub struct WorkingDepth {
    /// Subsampling factor.
    pub factor: u32,
    /// Width and height of the input image.
    pub full_size: (u32, u32),
    /// Depth in metres at working resolution (0 = none).
    pub depth: FloatImage,
}

impl WorkingDepth {
    /// Subsamples a full-resolution depth map.
    pub fn new(depth: &FloatImage, params: &StaticDepthParams) -> Self {
        let f = params.factor(depth.width());
        let w = depth.width().div_ceil(f);
        let h = depth.height().div_ceil(f);
        let d = FloatImage::from_fn(w, h, |i, j| {
            let z = depth.get_pixel(i * f, j * f).0[0];
            Luma([if z.is_finite() && z > 0.0 { z } else { 0.0 }])
        });
        Self {
            factor: f,
            full_size: depth.dimensions(),
            depth: d,
        }
    }
}

/// One neighbour view for the static depth: its subsampled depth and `T_cs`, which maps its
/// camera coordinates into the current camera's.
#[derive(Clone, Copy, Debug)]
pub struct DepthView<'a> {
    /// The neighbour's depth.
    pub depth: &'a WorkingDepth,
    /// Relative pose current ← neighbour.
    pub t_cs: Se3,
}

/// The static depth of the current view at working resolution (`NaN` where no surface is
/// supported by enough views).
#[derive(Clone, Debug, PartialEq)]
pub struct StaticDepth {
    /// Static depth in metres, `NaN` = unknown.
    pub depth: FloatImage,
    /// Subsampling factor relative to the input.
    pub factor: u32,
}
