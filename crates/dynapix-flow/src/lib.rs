//! Dense optical flow for dynapix: the [`FlowField`] type, the [`FlowProvider`] trait that
//! lets other flow sources plug in, the built-in DIS implementation (Kroeger et al.,
//! ECCV 2016) in [`dis`], Middlebury `.flo` files ([`flo`]), the Middlebury colour-wheel
//! picture ([`viz`]),
//! backward warping ([`warp`]) and end-point-error statistics ([`metrics`]).

use image::GrayImage;

pub mod dis;
pub mod flo;
pub mod metrics;
pub mod pairs;
pub mod plane;
mod validate;
pub mod variational;
pub mod viz;
pub mod warp;

pub use dis::{DisFlow, DisParams, Preset};
pub use flo::{read_flo, write_flo};
pub use metrics::{FlowErrorStats, flow_error};
pub use variational::VariationalParams;
pub use viz::{flow_to_color, flow_to_color_with_max};
pub use warp::warp_gray;

/// A dense flow field: for pixel x of image A, `B(x + f(x)) ≈ A(x)`.
#[derive(Clone, Debug, PartialEq)]
pub struct FlowField {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major `[dx, dy]` per pixel.
    pub data: Vec<[f32; 2]>,
}

impl FlowField {
    /// A zero flow of the given size.
    pub fn zeros(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            data: vec![[0.0, 0.0]; width as usize * height as usize],
        }
    }

    /// Flow vector at pixel (x, y).
    pub fn get(&self, x: u32, y: u32) -> [f32; 2] {
        self.data[y as usize * self.width as usize + x as usize]
    }

    /// A field with the same vector at every pixel.
    pub fn constant(width: u32, height: u32, f: [f32; 2]) -> Self {
        Self {
            width,
            height,
            data: vec![f; width as usize * height as usize],
        }
    }

    /// Whether every component is finite.
    pub fn is_finite(&self) -> bool {
        self.data
            .iter()
            .all(|f| f[0].is_finite() && f[1].is_finite())
    }
}

/// Errors of flow computation and flow files.
#[derive(Debug, thiserror::Error)]
pub enum FlowError {
    /// The two images differ in size.
    #[error("image sizes differ: {a:?} vs {b:?}")]
    SizeMismatch {
        /// Size of the first image.
        a: (u32, u32),
        /// Size of the second image.
        b: (u32, u32),
    },
    /// Reading or writing a flow file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A flow file is malformed or does not fit the request.
    #[error("{path}: {reason}")]
    BadFile {
        /// The file.
        path: std::path::PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Writing a flow file failed.
    #[error(transparent)]
    Write(#[from] dynapix_io::IoError),
    /// Any other failure, with a message.
    #[error("{0}")]
    Other(String),
}

/// A source of dense optical flow between two grey images (DIS, …).
pub trait FlowProvider: Send + Sync {
    /// Flow from `a` to `b`: `b(x + f(x)) ≈ a(x)`.
    fn flow(&self, a: &GrayImage, b: &GrayImage) -> Result<FlowField, FlowError>;
}
