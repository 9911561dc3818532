//! Dense Inverse Search optical flow (Kroeger, Timofte, Dai, Van Gool, ECCV 2016).
//!
//! Per pyramid level, from the coarsest to `finest_scale`:
//! 1. a grid of `patch_size²` patches every `patch_stride` pixels (the last row/column of
//!    patches is aligned to the image border so every pixel is covered);
//! 2. each patch displacement is found by inverse-compositional Gauss-Newton on the
//!    mean-normalised patch (paper §2.1; gradients and the 2×2 Hessian come from image A only,
//!    so they are computed once per patch), initialised from the coarser level. Like OpenCV's
//!    implementation, two sweeps (forward, then backward) first try the already-solved
//!    neighbours' displacements (spatial propagation) and keep the candidate with the lowest
//!    SSD. Sweeps run in fixed bands of patch rows (propagation does not cross a band), so the
//!    result does not depend on the number of threads. Also like OpenCV, each step is a
//!    fraction (`descent_step`, 1/8) of the Gauss-Newton step, the descent stops after the
//!    first step from a non-improving point, and a patch that moves further than its size
//!    keeps its start;
//! 3. densification (paper §2.2): every pixel averages the displacements of the patches that
//!    cover it, weighted by `1 / max(1, |B(x + u) − A(x)|)`;
//! 4. variational refinement (paper §2.3, [`crate::variational`]).
//!
//! The flow of the finest computed level is bilinearly upsampled to the input size.

mod densify;
#[cfg(test)]
mod fixtures;
mod patch;
mod search;
mod sums;

use self::densify::densify;
use self::patch::{LevelCtx, patch_origins, templates};
use self::search::sweep_band;
use crate::plane::{Plane, resize_flow, resize_flow_interleaved};
use crate::variational::{VariationalParams, refine};
use crate::{FlowError, FlowField, FlowProvider};
use image::GrayImage;
use rayon::prelude::*;

/// Border (pixels) added around image B at every level, so patches may leave the image.
pub(crate) const SEARCH_BORDER: usize = 16;
/// Hessians with a smaller determinant belong to textureless patches: they are not moved.
pub(crate) const MIN_HESSIAN_DET: f32 = 1e-6;

/// The parameter presets of OpenCV's `DISOpticalFlow` (same names and values).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// Finest scale 2, stride 4, 12 descent iterations, no variational refinement.
    Ultrafast,
    /// Finest scale 2, stride 4, 16 descent iterations, 5 refinement iterations.
    Fast,
    /// Finest scale 1, stride 3, 25 descent iterations, 5 refinement iterations.
    Medium,
}

impl std::str::FromStr for Preset {
    type Err = FlowError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "ultrafast" => Ok(Preset::Ultrafast),
            "fast" => Ok(Preset::Fast),
            "medium" => Ok(Preset::Medium),
            other => Err(FlowError::Other(format!(
                "unknown DIS preset {other:?} (expected ultrafast, fast or medium)"
            ))),
        }
    }
}

/// Parameters of [`DisFlow`]. `Default` is the `medium` preset.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct DisParams {
    /// Finest pyramid level that is computed (0 = full resolution); finer levels get the
    /// bilinearly upsampled flow.
    pub finest_scale: usize,
    /// Coarsest level; `None` chooses it from the image size like OpenCV
    /// (`round(log2(max(w,h) / (4·patch_size)))`, capped so the level holds a patch).
    pub coarsest_scale: Option<usize>,
    /// Side of the square patches.
    pub patch_size: usize,
    /// Distance between neighbouring patches.
    pub patch_stride: usize,
    /// Gauss-Newton iterations per patch (split over the two sweeps with propagation).
    pub grad_descent_iterations: usize,
    /// Fraction of the Gauss-Newton step taken per descent iteration. OpenCV uses
    /// unnormalised Sobel gradients (8× the derivative) with the plain Gauss-Newton formula,
    /// so its steps are 1/8 of the full step; the default keeps that behaviour, which
    /// also measured best here (docs/bench/flow.md).
    pub descent_step: f32,
    /// Compare patches after subtracting their mean (robust to brightness changes).
    pub use_mean_normalization: bool,
    /// Try the neighbours' displacements before descending (two sweeps).
    pub use_spatial_propagation: bool,
    /// Number of horizontal bands of patch rows for the sweeps (the unit of parallel work;
    /// propagation does not cross bands). Fixed, like OpenCV's 8 stripes, so results do not
    /// depend on the thread count.
    pub propagation_bands: usize,
    /// Variational refinement per level (`fixed_point_iterations = 0` disables it).
    pub variational: VariationalParams,
}

impl DisParams {
    /// Parameters of a preset (OpenCV 4.x `DISOpticalFlow::create(preset)` values).
    pub fn preset(preset: Preset) -> Self {
        let (finest_scale, patch_stride, grad_descent_iterations, vr_iterations) = match preset {
            Preset::Ultrafast => (2, 4, 12, 0),
            Preset::Fast => (2, 4, 16, 5),
            Preset::Medium => (1, 3, 25, 5),
        };
        Self {
            finest_scale,
            coarsest_scale: None,
            patch_size: 8,
            patch_stride,
            grad_descent_iterations,
            descent_step: 0.125,
            use_mean_normalization: true,
            use_spatial_propagation: true,
            propagation_bands: 8,
            variational: VariationalParams {
                fixed_point_iterations: vr_iterations,
                ..VariationalParams::default()
            },
        }
    }

    /// Checks the parameters a flow cannot run without: positive patch size, stride and
    /// number of bands.
    pub fn validate(&self) -> Result<(), FlowError> {
        if self.patch_size == 0 || self.patch_stride == 0 || self.propagation_bands == 0 {
            return Err(FlowError::Other(format!(
                "invalid DIS parameters: patch_size {}, patch_stride {}, propagation_bands {} must be > 0",
                self.patch_size, self.patch_stride, self.propagation_bands
            )));
        }
        Ok(())
    }
}

impl Default for DisParams {
    fn default() -> Self {
        Self::preset(Preset::Medium)
    }
}

/// The DIS flow provider.
#[derive(Clone, Debug, Default)]
pub struct DisFlow {
    /// Algorithm parameters.
    pub params: DisParams,
}

impl DisFlow {
    /// A provider with the given parameters.
    pub fn new(params: DisParams) -> Self {
        Self { params }
    }

    /// A provider with a preset's parameters.
    pub fn with_preset(preset: Preset) -> Self {
        Self::new(DisParams::preset(preset))
    }

    /// Flow from `a` to `b` on `f32` intensity planes (values in `[0, 255]`), returned as
    /// (u, v) planes. Errors only if the sizes differ or the parameters are invalid.
    pub fn compute_planes(&self, a: &Plane, b: &Plane) -> Result<(Plane, Plane), FlowError> {
        if (a.w, a.h) != (b.w, b.h) {
            return Err(FlowError::SizeMismatch {
                a: (a.w as u32, a.h as u32),
                b: (b.w as u32, b.h as u32),
            });
        }
        self.check_params()?;
        let (w, h) = (a.w, a.h);
        if w == 0 || h == 0 {
            return Ok((Plane::zeros(w, h), Plane::zeros(w, h)));
        }
        let (finest, coarsest) = scale_range(w, h, &self.params);
        let pyr_a = pyramid(a.clone(), 0, finest, coarsest);
        let pyr_b = pyramid(b.clone(), 0, finest, coarsest);
        let (u, v) = self.coarse_to_fine(&pyr_a, &pyr_b);
        if (u.w, u.h) == (w, h) {
            Ok((u, v))
        } else {
            Ok(resize_flow(&u, &v, w, h))
        }
    }

    fn check_params(&self) -> Result<(), FlowError> {
        self.params.validate()
    }

    /// Runs the levels from the coarsest to the finest; `pyr_*[i]` is level `finest + i`.
    /// Returns the flow at the finest level.
    fn coarse_to_fine(&self, pyr_a: &[Plane], pyr_b: &[Plane]) -> (Plane, Plane) {
        let p = &self.params;
        let mut flow: Option<(Plane, Plane)> = None;
        for (ia, ib) in pyr_a.iter().zip(pyr_b).rev() {
            let (mut u, mut v) = match flow.take() {
                None => (Plane::zeros(ia.w, ia.h), Plane::zeros(ia.w, ia.h)),
                Some((pu, pv)) => resize_flow(&pu, &pv, ia.w, ia.h),
            };
            dis_level(ia, ib, &mut u, &mut v, p);
            refine(ia, ib, &mut u, &mut v, &p.variational);
            flow = Some((u, v));
        }
        flow.unwrap_or_else(|| (Plane::zeros(1, 1), Plane::zeros(1, 1)))
    }
}

/// Levels `finest..=coarsest` of the pyramid whose level `start` is `base`.
fn pyramid(base: Plane, start: usize, finest: usize, coarsest: usize) -> Vec<Plane> {
    let mut cur = base;
    for _ in start..finest {
        cur = cur.downsample2();
    }
    let mut levels = vec![cur];
    for _ in finest..coarsest {
        let next = levels[levels.len() - 1].downsample2();
        levels.push(next);
    }
    levels
}

impl FlowProvider for DisFlow {
    fn flow(&self, a: &GrayImage, b: &GrayImage) -> Result<FlowField, FlowError> {
        if a.dimensions() != b.dimensions() {
            return Err(FlowError::SizeMismatch {
                a: a.dimensions(),
                b: b.dimensions(),
            });
        }
        self.check_params()?;
        let (w, h) = (a.width() as usize, a.height() as usize);
        if w == 0 || h == 0 {
            return Ok(FlowField::zeros(a.width(), a.height()));
        }
        let (finest, coarsest) = scale_range(w, h, &self.params);
        // Start the pyramid from the 8-bit image: full-resolution float copies are only made
        // when level 0 is computed.
        let base = |img: &GrayImage| {
            if finest == 0 {
                pyramid(Plane::from_gray(img), 0, 0, coarsest)
            } else {
                pyramid(Plane::downsample2_gray(img), 1, finest, coarsest)
            }
        };
        let (pyr_a, pyr_b) = rayon::join(|| base(a), || base(b));
        let (u, v) = self.coarse_to_fine(&pyr_a, &pyr_b);
        let data = if (u.w, u.h) == (w, h) {
            u.data.iter().zip(&v.data).map(|(&x, &y)| [x, y]).collect()
        } else {
            resize_flow_interleaved(&u, &v, w, h)
        };
        Ok(FlowField {
            width: a.width(),
            height: a.height(),
            data,
        })
    }
}

/// Finest and coarsest pyramid level for an image of `w × h`.
fn scale_range(w: usize, h: usize, p: &DisParams) -> (usize, usize) {
    // Deepest level that still has at least one pixel in each direction.
    let mut max_level = 0;
    while (w >> (max_level + 1)) >= 1 && (h >> (max_level + 1)) >= 1 && max_level < 30 {
        max_level += 1;
    }
    let coarsest = match p.coarsest_scale {
        Some(c) => c,
        None => {
            let ps = p.patch_size as f64;
            let by_size = ((w.max(h) as f64 / (4.0 * ps)).log2() + 0.5).floor();
            let fits = (w.min(h) as f64 / ps).log2().floor();
            by_size.min(fits).max(0.0) as usize
        }
    };
    let coarsest = coarsest.min(max_level);
    let finest = p.finest_scale.min(coarsest);
    (finest, coarsest)
}

/// Patch search and densification at one level; `(u, v)` holds the initial dense flow on
/// entry and the densified flow on return.
fn dis_level(a: &Plane, b: &Plane, u: &mut Plane, v: &mut Plane, p: &DisParams) {
    let ps = p.patch_size;
    let xs = patch_origins(a.w, ps, p.patch_stride);
    let ys = patch_origins(a.h, ps, p.patch_stride);
    if xs.is_empty() || ys.is_empty() || p.grad_descent_iterations == 0 {
        return;
    }
    let (ax, ay) = a.sobel();
    let bp = b.padded(SEARCH_BORDER);
    let ctx = LevelCtx {
        a,
        ax: &ax,
        ay: &ay,
        bp: &bp,
        ps,
        mean_norm: p.use_mean_normalization,
        step: p.descent_step,
    };
    let nx = xs.len();
    let half = ps as f32 * 0.5;
    // Initial displacement of each patch: the dense flow at the patch centre.
    let mut su = vec![0.0f32; nx * ys.len()];
    let mut sv = vec![0.0f32; nx * ys.len()];
    for (r, &py) in ys.iter().enumerate() {
        for (c, &px) in xs.iter().enumerate() {
            let cx = px as f32 + half - 0.5;
            let cy = py as f32 + half - 0.5;
            su[r * nx + c] = u.bilinear(cx, cy);
            sv[r * nx + c] = v.bilinear(cx, cy);
        }
    }
    let band_rows = ys.len().div_ceil(p.propagation_bands);
    let band = band_rows * nx;
    let passes: &[bool] = if p.use_spatial_propagation {
        &[true, false]
    } else {
        &[true]
    };
    // Each patch's template depends on image A only: made once, used by both sweeps.
    let tmpl = templates(&ctx, &xs, &ys);
    let total = p.grad_descent_iterations;
    for (k, &forward) in passes.iter().enumerate() {
        // Split the iterations over the sweeps so the total matches the parameter.
        let iters = total / passes.len() + usize::from(k < total % passes.len());
        su.par_chunks_mut(band)
            .zip(sv.par_chunks_mut(band))
            .zip(tmpl.par_chunks(band))
            .enumerate()
            .for_each(|(bi, ((bu, bv), bt))| {
                let row0 = bi * band_rows;
                sweep_band(
                    &ctx,
                    &xs,
                    &ys,
                    row0,
                    bt,
                    bu,
                    bv,
                    forward,
                    iters,
                    p.use_spatial_propagation,
                );
            });
    }
    densify(&ctx, &xs, &ys, &su, &sv, u, v);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_range_matches_opencv_rule_for_vga() {
        let p = DisParams::preset(Preset::Medium);
        assert_eq!(scale_range(640, 480, &p), (1, 4));
        let p = DisParams::preset(Preset::Fast);
        assert_eq!(scale_range(640, 480, &p), (2, 4));
        assert_eq!(scale_range(1, 1, &p), (0, 0));
    }

    use crate::pairs;

    fn interior_epe(f: &FlowField, gt: [f32; 2], margin: u32) -> f32 {
        let mut sum = 0.0;
        let mut n = 0.0;
        for y in margin..f.height - margin {
            for x in margin..f.width - margin {
                let v = f.get(x, y);
                sum += ((v[0] - gt[0]).powi(2) + (v[1] - gt[1]).powi(2)).sqrt();
                n += 1.0;
            }
        }
        sum / n
    }

    #[test]
    fn subpixel_translation_is_recovered() {
        let (w, h) = (192, 144);
        let b = pairs::texture(w, h);
        for t in [[0.37f32, -0.61], [-1.25, 0.8], [2.6, 1.45]] {
            let a = pairs::make_a(&b, &FlowField::constant(w, h, t)).unwrap();
            let f = DisFlow::with_preset(Preset::Medium).flow(&a, &b).unwrap();
            let epe = interior_epe(&f, t, 16);
            eprintln!("translation {t:?}: interior EPE {epe:.4}");
            assert!(epe < 0.05, "translation {t:?}: interior EPE {epe}");
        }
    }

    #[test]
    fn identical_images_give_zero_flow() {
        let img = pairs::texture(97, 61);
        for preset in [Preset::Ultrafast, Preset::Fast, Preset::Medium] {
            let f = DisFlow::with_preset(preset).flow(&img, &img).unwrap();
            let max = f
                .data
                .iter()
                .map(|v| v[0].abs().max(v[1].abs()))
                .fold(0.0f32, f32::max);
            assert!(max < 1e-4, "{preset:?}: max |flow| {max}");
        }
    }

    #[test]
    fn degenerate_inputs_stay_finite() {
        let sizes = [
            (0, 0),
            (1, 1),
            (5, 3),
            (3, 5),
            (8, 8),
            (9, 7),
            (37, 29),
            (101, 7),
            (130, 97),
            (3, 200),
            (200, 3),
            (9, 300),
        ];
        for (w, h) in sizes {
            let tex = pairs::texture(w, h);
            let uniform = GrayImage::from_pixel(w, h, image::Luma([77]));
            let shifted = pairs::make_a(&tex, &FlowField::constant(w, h, [0.7, -0.3])).unwrap();
            for preset in [Preset::Ultrafast, Preset::Fast, Preset::Medium] {
                let dis = DisFlow::with_preset(preset);
                for (a, b) in [(&uniform, &uniform), (&shifted, &tex), (&uniform, &tex)] {
                    let f = dis.flow(a, b).unwrap();
                    assert_eq!((f.width, f.height), (w, h));
                    assert_eq!(f.data.len(), (w * h) as usize);
                    assert!(f.is_finite(), "{w}x{h} {preset:?}: non-finite flow");
                }
            }
        }
    }

    #[test]
    fn displacements_beyond_the_border_stay_finite() {
        let (w, h) = (64, 48);
        let b = pairs::texture(w, h);
        for t in [[30.0f32, -25.0], [-60.0, 0.0]] {
            let a = pairs::make_a(&b, &FlowField::constant(w, h, t)).unwrap();
            for preset in [Preset::Ultrafast, Preset::Medium] {
                let f = DisFlow::with_preset(preset).flow(&a, &b).unwrap();
                assert!(f.is_finite(), "{t:?} {preset:?}");
            }
        }
    }

    #[test]
    fn size_mismatch_and_bad_params_are_errors() {
        let a = GrayImage::new(10, 10);
        let b = GrayImage::new(11, 10);
        assert!(matches!(
            DisFlow::default().flow(&a, &b),
            Err(FlowError::SizeMismatch { .. })
        ));
        let p = DisParams {
            patch_stride: 0,
            ..DisParams::default()
        };
        assert!(DisFlow::new(p).flow(&a, &a).is_err());
    }

    #[test]
    fn results_do_not_depend_on_thread_count() {
        let (w, h) = (160, 120);
        let b = pairs::texture(w, h);
        let a = pairs::make_a(&b, &pairs::smooth_nonrigid(w, h, 3.0)).unwrap();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| DisFlow::default().flow(&a, &b).unwrap())
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn preset_parses_case_insensitively() {
        assert_eq!("Medium".parse::<Preset>().unwrap(), Preset::Medium);
        assert!("slow".parse::<Preset>().is_err());
    }
}
