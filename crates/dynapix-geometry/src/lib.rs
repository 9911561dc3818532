//! Geometry for dynapix: rigid and similarity transforms (SE3/Sim3) with their Lie-group
//! maps, the pinhole camera with radial-tangential distortion, trajectory alignment
//! (Horn/Umeyama) and PnP. Pure maths: no file access.

pub mod camera;
pub mod se3;

pub use camera::PinholeCamera;
pub use se3::Se3;
