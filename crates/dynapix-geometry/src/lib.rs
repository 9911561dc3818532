//! Geometry for dynapix: rigid and similarity transforms (SE3/Sim3) with their Lie-group
//! maps, the pinhole camera with radial-tangential distortion, trajectory alignment
//! (Horn/Umeyama), interpolation, PnP and triangulation. Pure maths: no file access.

#![forbid(unsafe_code)]

pub mod align;
pub mod camera;
pub mod interp;
pub mod pnp;
pub mod se3;
pub mod sim3;
pub mod stats;
pub mod triangulate;

pub use camera::{PinholeCamera, PixelRays};
pub use se3::Se3;
