//! Dense optical flow for dynapix: the [`FlowField`] type, the [`FlowProvider`] trait that
//! lets other flow sources plug in, and the built-in DIS implementation (Kroeger et al.,
//! ECCV 2016).

use image::GrayImage;

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
    /// Any other failure, with a message.
    #[error("{0}")]
    Other(String),
}

/// A source of dense optical flow between two grey images (DIS, precomputed files, …).
pub trait FlowProvider: Send + Sync {
    /// Flow from `a` to `b`: `b(x + f(x)) ≈ a(x)`.
    fn flow(&self, a: &GrayImage, b: &GrayImage) -> Result<FlowField, FlowError>;
}
