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

use crate::plane::{Plane, min_rows, resize_flow, resize_flow_interleaved, simd};
use crate::variational::{VariationalParams, refine};
use crate::{FlowError, FlowField, FlowProvider};
use image::GrayImage;
use rayon::prelude::*;

/// Border (pixels) added around image B at every level, so patches may leave the image.
const SEARCH_BORDER: usize = 16;
/// Hessians with a smaller determinant belong to textureless patches: they are not moved.
const MIN_HESSIAN_DET: f32 = 1e-6;

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

/// Patch origins along one axis: every `stride`, plus one aligned to the far border.
fn patch_origins(len: usize, ps: usize, stride: usize) -> Vec<usize> {
    if len < ps {
        return Vec::new();
    }
    let last = len - ps;
    let mut v: Vec<usize> = (0..=last).step_by(stride).collect();
    if v.last() != Some(&last) {
        v.push(last);
    }
    v
}

/// Inputs of the patch search at one level, shared by all threads.
struct LevelCtx<'a> {
    a: &'a Plane,
    ax: &'a Plane,
    ay: &'a Plane,
    /// Image B padded by `SEARCH_BORDER`.
    bp: &'a Plane,
    ps: usize,
    mean_norm: bool,
    /// Fraction of the Gauss-Newton step taken per iteration.
    step: f32,
}

/// What the descent needs about one patch of A: the inverse of its (mean-normalised)
/// Hessian and the sums of its gradients (for the mean-normalisation correction).
#[derive(Clone, Copy)]
struct Template {
    hinv: [f32; 3],
    sum_gx: f32,
    sum_gy: f32,
    /// False for textureless patches: they take part in propagation but do not descend.
    textured: bool,
}

/// Hessian and gradient sums of the patch at (px, py).
#[inline(always)]
fn load_template(ctx: &LevelCtx, px: usize, py: usize) -> Template {
    let (ps, w) = (ctx.ps, ctx.a.w);
    let (mut sx, mut sy, mut hxx, mut hxy, mut hyy) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for j in 0..ps {
        let o = (py + j) * w + px;
        let gx = &ctx.ax.data[o..o + ps];
        let gy = &ctx.ay.data[o..o + ps];
        for (&x, &y) in gx.iter().zip(gy) {
            sx += x;
            sy += y;
            hxx += x * x;
            hxy += x * y;
            hyy += y * y;
        }
    }
    // With mean normalisation the exact Hessian would use mean-removed gradients; like
    // OpenCV we keep the raw one, which damps the steps and measured better (see
    // docs/bench/flow.md).
    let det = hxx * hyy - hxy * hxy;
    // Relative threshold: the Hessian scales with the squared gradient magnitude.
    let scale = (hxx + hyy).max(f32::MIN_POSITIVE);
    let textured = det > MIN_HESSIAN_DET * scale * scale && det.is_finite();
    let k = ctx.step;
    let hinv = if textured {
        [k * hyy / det, -k * hxy / det, k * hxx / det]
    } else {
        [0.0; 3]
    };
    Template {
        hinv,
        sum_gx: sx,
        sum_gy: sy,
        textured,
    }
}

/// The templates of all patches, row-major (patch row `r`, column `c` at `r · xs.len() + c`).
fn templates(ctx: &LevelCtx, xs: &[usize], ys: &[usize]) -> Vec<Template> {
    let nx = xs.len();
    let empty = Template {
        hinv: [0.0; 3],
        sum_gx: 0.0,
        sum_gy: 0.0,
        textured: false,
    };
    let mut out = vec![empty; nx * ys.len()];
    if nx == 0 {
        return out;
    }
    out.par_chunks_mut(nx)
        .zip(ys.par_iter())
        .with_min_len(min_rows(nx * ctx.ps * ctx.ps))
        .for_each(|(row, &py)| {
            for (t, &px) in row.iter_mut().zip(xs) {
                *t = load_template(ctx, px, py);
            }
        });
    out
}

/// Clamps a displacement so the patch stays inside the padded image B.
#[inline(always)]
fn clamp_disp(ctx: &LevelCtx, px: usize, py: usize, u: f32, v: f32) -> (f32, f32) {
    let b = SEARCH_BORDER as f32;
    let max_x = (ctx.bp.w - ctx.ps - 1) as f32 - b - px as f32;
    let max_y = (ctx.bp.h - ctx.ps - 1) as f32 - b - py as f32;
    let min_x = -b - px as f32;
    let min_y = -b - py as f32;
    let u = if u.is_finite() {
        u.clamp(min_x, max_x)
    } else {
        0.0
    };
    let v = if v.is_finite() {
        v.clamp(min_y, max_y)
    } else {
        0.0
    };
    (u, v)
}

/// Raw sums over the patch of the residual `d = B(x+u) − A(x)`: Σd, Σd², Σd·Ax, Σd·Ay.
/// All pixels of a patch share the bilinear weights; with a compile-time patch width the
/// per-lane accumulators vectorise.
#[inline(always)]
fn patch_sums<const N: usize>(ctx: &LevelCtx, px: usize, py: usize, x: f32, y: f32) -> [f32; 4] {
    #[inline(always)]
    fn arr<const N: usize>(data: &[f32], o: usize) -> Option<&[f32; N]> {
        data.get(o..o + N)?.try_into().ok()
    }
    let (aw, bw) = (ctx.a.w, ctx.bp.w);
    // x, y >= 0 (clamped displacement in the padded image): truncation is floor.
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let w00 = (1.0 - fx) * (1.0 - fy);
    let w01 = fx * (1.0 - fy);
    let w10 = (1.0 - fx) * fy;
    let w11 = fx * fy;
    let mut sd = [0.0f32; N];
    let mut sdd = [0.0f32; N];
    let mut sdx = [0.0f32; N];
    let mut sdy = [0.0f32; N];
    let b = &ctx.bp.data;
    for j in 0..N {
        let ob = (y0 + j) * bw + x0;
        let oa = (py + j) * aw + px;
        let rows = (
            arr::<N>(b, ob),
            arr::<N>(b, ob + 1),
            arr::<N>(b, ob + bw),
            arr::<N>(b, ob + bw + 1),
        );
        let tmpl = (
            arr::<N>(&ctx.a.data, oa),
            arr::<N>(&ctx.ax.data, oa),
            arr::<N>(&ctx.ay.data, oa),
        );
        let ((Some(r0l), Some(r0r), Some(r1l), Some(r1r)), (Some(a), Some(gx), Some(gy))) =
            (rows, tmpl)
        else {
            // Unreachable for clamped displacements; an empty patch costs nothing.
            break;
        };
        for i in 0..N {
            let d = w00 * r0l[i] + w01 * r0r[i] + w10 * r1l[i] + w11 * r1r[i] - a[i];
            sd[i] += d;
            sdd[i] += d * d;
            sdx[i] += d * gx[i];
            sdy[i] += d * gy[i];
        }
    }
    [
        sum_in_order(&sd),
        sum_in_order(&sdd),
        sum_in_order(&sdx),
        sum_in_order(&sdy),
    ]
}

/// The sum of `lanes` from the first to the last: the same operations, in the same order,
/// as `lanes.iter().sum()` (whose fold starts at −0.0, and −0.0 + x = x), but inlined into
/// the calling kernel instead of a call per sum.
#[inline(always)]
fn sum_in_order<const N: usize>(lanes: &[f32; N]) -> f32 {
    let mut s = -0.0f32;
    for &x in lanes {
        s += x;
    }
    s
}

/// Start offsets into B and A and the bilinear fractions of an 8×8 patch at (x, y) / (px, py),
/// or `None` when any row the SIMD kernels read would leave the buffers. Checking the ranges
/// once here keeps their loops free of bounds checks and makes their unchecked loads sound.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn patch_8_window(
    ctx: &LevelCtx,
    px: usize,
    py: usize,
    x: f32,
    y: f32,
) -> Option<(usize, usize, f32, f32)> {
    const N: usize = 8;
    let (aw, bw) = (ctx.a.w, ctx.bp.w);
    let (x0, y0) = (x as usize, y as usize);
    let b_end = (y0 + N) * bw + x0 + N + 1;
    let a_end = (py + N - 1) * aw + px + N;
    if b_end > ctx.bp.data.len()
        || a_end > ctx.a.data.len()
        || a_end > ctx.ax.data.len()
        || a_end > ctx.ay.data.len()
    {
        return None;
    }
    Some((y0 * bw + x0, py * aw + px, x - x0 as f32, y - y0 as f32))
}

/// [`patch_sums`] for 8×8 patches with SSE2 (part of every x86-64 CPU): two 4-lane vectors
/// per row. Lane order and summation order equal the portable version's.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn patch_sums_8_sse(ctx: &LevelCtx, px: usize, py: usize, x: f32, y: f32) -> [f32; 4] {
    use std::arch::x86_64::*;
    const N: usize = 8;
    let (aw, bw) = (ctx.a.w, ctx.bp.w);
    let b = &ctx.bp.data;
    let Some((b_start, a_start, fx, fy)) = patch_8_window(ctx, px, py, x, y) else {
        return [0.0; 4];
    };
    let (bp, ap) = (b.as_ptr(), ctx.a.data.as_ptr());
    let (gxp, gyp) = (ctx.ax.data.as_ptr(), ctx.ay.data.as_ptr());
    let lanes = |v: __m128| -> [f32; 4] {
        let mut o = [0.0f32; 4];
        // SAFETY: `o` has room for 4 floats.
        unsafe { _mm_storeu_ps(o.as_mut_ptr(), v) };
        o
    };
    // SAFETY: all loads are within the ranges checked above (rows y0..=y0+N of B from x0 to
    // x0+N inclusive, rows py..py+N of A and its gradients from px to px+N-1).
    let acc = unsafe {
        let w00 = _mm_set1_ps((1.0 - fx) * (1.0 - fy));
        let w01 = _mm_set1_ps(fx * (1.0 - fy));
        let w10 = _mm_set1_ps((1.0 - fx) * fy);
        let w11 = _mm_set1_ps(fx * fy);
        let z = _mm_setzero_ps();
        let (mut sd0, mut sd1, mut sdd0, mut sdd1) = (z, z, z, z);
        let (mut sx0, mut sx1, mut sy0, mut sy1) = (z, z, z, z);
        for j in 0..N {
            let ob = b_start + j * bw;
            let oa = a_start + j * aw;
            for (half, (sd, sdd, sx, sy)) in [
                (0usize, (&mut sd0, &mut sdd0, &mut sx0, &mut sy0)),
                (4, (&mut sd1, &mut sdd1, &mut sx1, &mut sy1)),
            ] {
                let r0l = _mm_loadu_ps(bp.add(ob + half));
                let r0r = _mm_loadu_ps(bp.add(ob + half + 1));
                let r1l = _mm_loadu_ps(bp.add(ob + bw + half));
                let r1r = _mm_loadu_ps(bp.add(ob + bw + half + 1));
                let a = _mm_loadu_ps(ap.add(oa + half));
                let t0 = _mm_add_ps(_mm_mul_ps(w00, r0l), _mm_mul_ps(w01, r0r));
                let t1 = _mm_add_ps(t0, _mm_mul_ps(w10, r1l));
                let d = _mm_sub_ps(_mm_add_ps(t1, _mm_mul_ps(w11, r1r)), a);
                *sd = _mm_add_ps(*sd, d);
                *sdd = _mm_add_ps(*sdd, _mm_mul_ps(d, d));
                *sx = _mm_add_ps(*sx, _mm_mul_ps(d, _mm_loadu_ps(gxp.add(oa + half))));
                *sy = _mm_add_ps(*sy, _mm_mul_ps(d, _mm_loadu_ps(gyp.add(oa + half))));
            }
        }
        [(sd0, sd1), (sdd0, sdd1), (sx0, sx1), (sy0, sy1)]
    };
    acc.map(|(lo, hi)| {
        let (l, h) = (lanes(lo), lanes(hi));
        sum_in_order(&[l[0], l[1], l[2], l[3], h[0], h[1], h[2], h[3]])
    })
}

/// [`patch_sums_8_sse`] with one 8-lane AVX vector per row; same lanes, same summation
/// order, so the same result.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn patch_sums_8_avx(
    avx2: dynapix_simd::Avx2,
    ctx: &LevelCtx,
    px: usize,
    py: usize,
    x: f32,
    y: f32,
) -> [f32; 4] {
    use std::arch::x86_64::*;
    const N: usize = 8;
    let (aw, bw) = (ctx.a.w, ctx.bp.w);
    let b = &ctx.bp.data;
    let Some((b_start, a_start, fx, fy)) = patch_8_window(ctx, px, py, x, y) else {
        return [0.0; 4];
    };
    let (bp, ap) = (b.as_ptr(), ctx.a.data.as_ptr());
    let (gxp, gyp) = (ctx.ax.data.as_ptr(), ctx.ay.data.as_ptr());
    let w00 = _mm256_set1_ps((1.0 - fx) * (1.0 - fy));
    let w01 = _mm256_set1_ps(fx * (1.0 - fy));
    let w10 = _mm256_set1_ps((1.0 - fx) * fy);
    let w11 = _mm256_set1_ps(fx * fy);
    let (mut sd, mut sdd) = (_mm256_setzero_ps(), _mm256_setzero_ps());
    let (mut sx, mut sy) = (_mm256_setzero_ps(), _mm256_setzero_ps());
    for j in 0..N {
        let ob = b_start + j * bw;
        let oa = a_start + j * aw;
        // SAFETY: all loads are within the ranges checked above (8 floats from each offset).
        unsafe {
            let r0l = _mm256_loadu_ps(bp.add(ob));
            let r0r = _mm256_loadu_ps(bp.add(ob + 1));
            let r1l = _mm256_loadu_ps(bp.add(ob + bw));
            let r1r = _mm256_loadu_ps(bp.add(ob + bw + 1));
            let a = _mm256_loadu_ps(ap.add(oa));
            let t0 = _mm256_add_ps(_mm256_mul_ps(w00, r0l), _mm256_mul_ps(w01, r0r));
            let t1 = _mm256_add_ps(t0, _mm256_mul_ps(w10, r1l));
            let d = _mm256_sub_ps(_mm256_add_ps(t1, _mm256_mul_ps(w11, r1r)), a);
            sd = _mm256_add_ps(sd, d);
            sdd = _mm256_add_ps(sdd, _mm256_mul_ps(d, d));
            sx = _mm256_add_ps(sx, _mm256_mul_ps(d, _mm256_loadu_ps(gxp.add(oa))));
            sy = _mm256_add_ps(sy, _mm256_mul_ps(d, _mm256_loadu_ps(gyp.add(oa))));
        }
    }
    sum_lanes_in_order_4(avx2, sd, sdd, sx, sy)
}

/// [`sum_in_order`] of the 8 lanes of each of four vectors, all four at once: the vectors
/// are transposed so that lane i of every one lands in one 4-wide vector, then those are
/// added in lane order, `((l0 + l1) + l2) + …`, four sums per instruction. The same
/// additions in the same order as four calls of [`sum_in_order`], so the same bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn sum_lanes_in_order_4(
    _: dynapix_simd::Avx2,
    a: std::arch::x86_64::__m256,
    b: std::arch::x86_64::__m256,
    c: std::arch::x86_64::__m256,
    d: std::arch::x86_64::__m256,
) -> [f32; 4] {
    use std::arch::x86_64::*;
    // [a0 b0 a1 b1 | a4 b4 a5 b5], [a2 b2 a3 b3 | a6 b6 a7 b7], the same for c, d.
    let (ab_lo, ab_hi) = (_mm256_unpacklo_ps(a, b), _mm256_unpackhi_ps(a, b));
    let (cd_lo, cd_hi) = (_mm256_unpacklo_ps(c, d), _mm256_unpackhi_ps(c, d));
    // w_k = [a_k b_k c_k d_k | a_{k+4} b_{k+4} c_{k+4} d_{k+4}].
    let w0 = _mm256_shuffle_ps::<0x44>(ab_lo, cd_lo);
    let w1 = _mm256_shuffle_ps::<0xEE>(ab_lo, cd_lo);
    let w2 = _mm256_shuffle_ps::<0x44>(ab_hi, cd_hi);
    let w3 = _mm256_shuffle_ps::<0xEE>(ab_hi, cd_hi);
    let lo = |w| _mm256_castps256_ps128(w);
    let hi = |w| _mm256_extractf128_ps::<1>(w);
    let mut s = _mm_add_ps(lo(w0), lo(w1));
    s = _mm_add_ps(s, lo(w2));
    s = _mm_add_ps(s, lo(w3));
    s = _mm_add_ps(s, hi(w0));
    s = _mm_add_ps(s, hi(w1));
    s = _mm_add_ps(s, hi(w2));
    s = _mm_add_ps(s, hi(w3));
    let mut o = [0.0f32; 4];
    // SAFETY: `o` has room for 4 floats.
    unsafe { _mm_storeu_ps(o.as_mut_ptr(), s) };
    o
}

/// Scalar version of [`patch_sums`] for patch sizes without a specialised kernel.
#[inline(always)]
fn patch_sums_dyn(ctx: &LevelCtx, px: usize, py: usize, x: f32, y: f32) -> [f32; 4] {
    let (aw, bw, ps) = (ctx.a.w, ctx.bp.w, ctx.ps);
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let mut s = [0.0f32; 4];
    for j in 0..ps {
        let r0 = &ctx.bp.data[(y0 + j) * bw + x0..(y0 + j) * bw + x0 + ps + 1];
        let r1 = &ctx.bp.data[(y0 + j + 1) * bw + x0..(y0 + j + 1) * bw + x0 + ps + 1];
        let oa = (py + j) * aw + px;
        for i in 0..ps {
            let top = r0[i] + fx * (r0[i + 1] - r0[i]);
            let bot = r1[i] + fx * (r1[i + 1] - r1[i]);
            let d = top + fy * (bot - top) - ctx.a.data[oa + i];
            s[0] += d;
            s[1] += d * d;
            s[2] += d * ctx.ax.data[oa + i];
            s[3] += d * ctx.ay.data[oa + i];
        }
    }
    s
}

/// Patch cost at displacement (u, v) and the Gauss-Newton right-hand side:
/// `(SSD, Σ ∇A·d)`, both mean-normalised when enabled.
#[inline(always)]
fn evaluate(
    isa: Option<dynapix_simd::Avx2>,
    ctx: &LevelCtx,
    t: &Template,
    px: usize,
    py: usize,
    u: f32,
    v: f32,
) -> (f32, f32, f32) {
    let x = px as f32 + u + SEARCH_BORDER as f32;
    let y = py as f32 + v + SEARCH_BORDER as f32;
    let [sd, sdd, sdx, sdy] = match ctx.ps {
        #[cfg(target_arch = "x86_64")]
        8 => match isa {
            // SAFETY: the token proves the CPU has AVX2.
            Some(avx2) => unsafe { patch_sums_8_avx(avx2, ctx, px, py, x, y) },
            None => patch_sums_8_sse(ctx, px, py, x, y),
        },
        #[cfg(not(target_arch = "x86_64"))]
        8 => patch_sums::<8>(ctx, px, py, x, y),
        12 => patch_sums::<12>(ctx, px, py, x, y),
        16 => patch_sums::<16>(ctx, px, py, x, y),
        _ => patch_sums_dyn(ctx, px, py, x, y),
    };
    if ctx.mean_norm {
        let n = (ctx.ps * ctx.ps) as f32;
        (
            (sdd - sd * sd / n).max(0.0),
            sdx - sd * t.sum_gx / n,
            sdy - sd * t.sum_gy / n,
        )
    } else {
        (sdd, sdx, sdy)
    }
}

/// Inverse-compositional Gauss-Newton from (u, v), whose evaluation is `start`. Like OpenCV,
/// each iteration evaluates the patch, steps, and stops after the first step taken from a
/// point whose cost did not decrease. A result further than the patch size from the start is
/// discarded (the match was lost).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn descend(
    isa: Option<dynapix_simd::Avx2>,
    ctx: &LevelCtx,
    t: &Template,
    px: usize,
    py: usize,
    u0: f32,
    v0: f32,
    start: (f32, f32, f32),
    iters: usize,
) -> (f32, f32) {
    let (mut u, mut v) = (u0, v0);
    let (mut ssd, mut bx, mut by) = start;
    let mut prev = f32::INFINITY;
    for it in 0..iters {
        if it > 0 {
            (ssd, bx, by) = evaluate(isa, ctx, t, px, py, u, v);
        }
        let du = t.hinv[0] * bx + t.hinv[1] * by;
        let dv = t.hinv[1] * bx + t.hinv[2] * by;
        (u, v) = clamp_disp(ctx, px, py, u - du, v - dv);
        if ssd >= prev {
            break;
        }
        prev = ssd;
    }
    let max_move2 = (ctx.ps * ctx.ps) as f32;
    if (u - u0).powi(2) + (v - v0).powi(2) > max_move2 {
        (u0, v0)
    } else {
        (u, v)
    }
}

/// One sweep over a band of patch rows (see [`sweep_band_impl`]), using AVX2 code when the
/// CPU has it. Both variants do the same operations in the same order (no fused multiply-add
/// is enabled), so the results are identical.
#[allow(clippy::too_many_arguments)]
fn sweep_band(
    ctx: &LevelCtx,
    xs: &[usize],
    ys: &[usize],
    row0: usize,
    tmpl: &[Template],
    su: &mut [f32],
    sv: &mut [f32],
    forward: bool,
    iters: usize,
    propagate: bool,
) {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        unsafe {
            sweep_band_avx2(
                avx2, ctx, xs, ys, row0, tmpl, su, sv, forward, iters, propagate,
            )
        };
        return;
    }
    sweep_band_impl(
        None, ctx, xs, ys, row0, tmpl, su, sv, forward, iters, propagate,
    );
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
fn sweep_band_avx2(
    avx2: dynapix_simd::Avx2,
    ctx: &LevelCtx,
    xs: &[usize],
    ys: &[usize],
    row0: usize,
    tmpl: &[Template],
    su: &mut [f32],
    sv: &mut [f32],
    forward: bool,
    iters: usize,
    propagate: bool,
) {
    sweep_band_impl(
        Some(avx2),
        ctx,
        xs,
        ys,
        row0,
        tmpl,
        su,
        sv,
        forward,
        iters,
        propagate,
    );
}

/// One sweep over a band of patch rows. `forward` goes left-to-right/top-down and proposes
/// the left and upper neighbours; backward the right and lower ones.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn sweep_band_impl(
    isa: Option<dynapix_simd::Avx2>,
    ctx: &LevelCtx,
    xs: &[usize],
    ys: &[usize],
    row0: usize,
    tmpl: &[Template],
    su: &mut [f32],
    sv: &mut [f32],
    forward: bool,
    iters: usize,
    propagate: bool,
) {
    let nx = xs.len();
    let rows = su.len() / nx;
    for rr in 0..rows {
        let r = if forward { rr } else { rows - 1 - rr };
        for cc in 0..nx {
            let c = if forward { cc } else { nx - 1 - cc };
            let idx = r * nx + c;
            let (px, py) = (xs[c], ys[row0 + r]);
            // Every stored displacement is clamped: densification samples B with it.
            let (mut bu, mut bv) = clamp_disp(ctx, px, py, su[idx], sv[idx]);
            su[idx] = bu;
            sv[idx] = bv;
            let t = tmpl[idx];
            if !t.textured && !propagate {
                continue;
            }
            let mut best = evaluate(isa, ctx, &t, px, py, bu, bv);
            if propagate {
                let horiz = if forward {
                    (c > 0).then(|| idx - 1)
                } else {
                    (c + 1 < nx).then(|| idx + 1)
                };
                let vert = if forward {
                    (r > 0).then(|| idx - nx)
                } else {
                    (r + 1 < rows).then(|| idx + nx)
                };
                for j in [horiz, vert].into_iter().flatten() {
                    let (cu, cv) = clamp_disp(ctx, px, py, su[j], sv[j]);
                    if cu == bu && cv == bv {
                        continue;
                    }
                    let e = evaluate(isa, ctx, &t, px, py, cu, cv);
                    if e.0 < best.0 {
                        best = e;
                        bu = cu;
                        bv = cv;
                    }
                }
            }
            let (u, v) = if t.textured {
                descend(isa, ctx, &t, px, py, bu, bv, best, iters)
            } else {
                (bu, bv)
            };
            su[idx] = u;
            sv[idx] = v;
        }
    }
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

/// Dense flow as the photometrically weighted average of the covering patches (paper §2.2),
/// compiled for AVX2 when the CPU has it, with patch rows of 8 pixels as whole vectors. Every
/// build does the same operations per pixel in the same order (no fused multiply-add), so the
/// results are identical (test `fixed_size_patch_rows_densify_the_same`).
fn densify(
    ctx: &LevelCtx,
    xs: &[usize],
    ys: &[usize],
    su: &[f32],
    sv: &[f32],
    u: &mut Plane,
    v: &mut Plane,
) {
    densify_rows::<true>(dynapix_simd::Avx2::detect(), ctx, xs, ys, su, sv, u, v);
}

/// [`densify`], with (`FIXED`) or without the patch rows of 8 pixels as fixed-size arrays,
/// which the compiler turns into whole-vector operations, and with (`isa`, when the CPU has
/// it) or without the rows compiled for AVX2 ([`simd`]).
#[inline(always)]
fn densify_rows<const FIXED: bool>(
    isa: Option<dynapix_simd::Avx2>,
    ctx: &LevelCtx,
    xs: &[usize],
    ys: &[usize],
    su: &[f32],
    sv: &[f32],
    u: &mut Plane,
    v: &mut Plane,
) {
    let (w, ps, nx) = (ctx.a.w, ctx.ps, xs.len());
    let bw = ctx.bp.w;
    u.data
        .par_chunks_mut(w)
        .zip(v.data.par_chunks_mut(w))
        .enumerate()
        .with_min_len(min_rows(w))
        .for_each_init(
            || vec![0.0f32; w],
            |wsum, (y, (ru, rv))| {
                simd(
                    isa,
                    #[inline(always)]
                    || {
                        wsum.fill(0.0);
                        ru.fill(0.0);
                        rv.fill(0.0);
                        let arow = &ctx.a.data[y * w..(y + 1) * w];
                        // Patch rows covering pixel row y (origins are sorted).
                        let r_lo = ys.partition_point(|&py| py + ps <= y);
                        let r_hi = ys.partition_point(|&py| py <= y);
                        for r in r_lo..r_hi {
                            for c in 0..nx {
                                let (pu, pv) = (su[r * nx + c], sv[r * nx + c]);
                                let px = xs[c];
                                let bx = px as f32 + pu + SEARCH_BORDER as f32;
                                let by = y as f32 + pv + SEARCH_BORDER as f32;
                                // Non-negative inside the padded image: truncation is floor.
                                let (x0, y0) = (bx as usize, by as usize);
                                let (fx, fy) = (bx - x0 as f32, by - y0 as f32);
                                let o0 = y0 * bw + x0;
                                let r0 = &ctx.bp.data[o0..o0 + ps + 1];
                                let r1 = &ctx.bp.data[o0 + bw..o0 + bw + ps + 1];
                                let acc = (
                                    &mut wsum[px..px + ps],
                                    &mut ru[px..px + ps],
                                    &mut rv[px..px + ps],
                                );
                                let a = &arow[px..px + ps];
                                if FIXED && ps == 8 {
                                    densify_patch_row::<8>(r0, r1, a, (fx, fy), (pu, pv), acc);
                                } else {
                                    densify_patch_row_dyn(r0, r1, a, (fx, fy), (pu, pv), acc);
                                }
                            }
                        }
                        for x in 0..w {
                            let inv = 1.0 / wsum[x];
                            ru[x] *= inv;
                            rv[x] *= inv;
                        }
                    },
                )
            },
        );
}

/// Adds one patch row's contribution to the dense flow: the photometric weight of each of
/// its pixels (B at the patch's displacement, bilinear, against A) into `wsum`, and the
/// weighted displacement into `ru` and `rv`. `b0` and `b1` are the two padded-B rows under
/// the patch row (at least `N + 1` values), `a` the A pixels (`N`), `f` the bilinear
/// fractions and `d` the displacement; `acc` is (`wsum`, `ru`, `rv`), `N` values each.
#[inline(always)]
fn densify_patch_row<const N: usize>(
    b0: &[f32],
    b1: &[f32],
    a: &[f32],
    f: (f32, f32),
    d: (f32, f32),
    acc: (&mut [f32], &mut [f32], &mut [f32]),
) {
    let (b0, b1, a) = (&b0[..N + 1], &b1[..N + 1], &a[..N]);
    let (wsum, ru, rv) = (&mut acc.0[..N], &mut acc.1[..N], &mut acc.2[..N]);
    let mut wt = [0.0f32; N];
    for i in 0..N {
        wt[i] = photometric_weight(b0[i], b0[i + 1], b1[i], b1[i + 1], a[i], f);
    }
    for i in 0..N {
        wsum[i] += wt[i];
        ru[i] += wt[i] * d.0;
        rv[i] += wt[i] * d.1;
    }
}

/// [`densify_patch_row`] for a patch width known only at run time (`a.len()` pixels).
#[inline(always)]
fn densify_patch_row_dyn(
    b0: &[f32],
    b1: &[f32],
    a: &[f32],
    f: (f32, f32),
    d: (f32, f32),
    acc: (&mut [f32], &mut [f32], &mut [f32]),
) {
    let (wsum, ru, rv) = acc;
    for (i, &ai) in a.iter().enumerate() {
        let wt = photometric_weight(b0[i], b0[i + 1], b1[i], b1[i + 1], ai, f);
        wsum[i] += wt;
        ru[i] += wt * d.0;
        rv[i] += wt * d.1;
    }
}

/// The densification weight `1 / max(|B(x + d) − A(x)|, 1)` of one pixel: B bilinear from
/// its four neighbours `t0 t1 / s0 s1` with fractions `f`.
#[inline(always)]
fn photometric_weight(t0: f32, t1: f32, s0: f32, s1: f32, a: f32, f: (f32, f32)) -> f32 {
    let top = t0 + f.0 * (t1 - t0);
    let bot = s0 + f.0 * (s1 - s0);
    let diff = (top + f.1 * (bot - top) - a).abs();
    1.0 / diff.max(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patch_origins_cover_the_axis() {
        assert_eq!(patch_origins(20, 8, 4), vec![0, 4, 8, 12]);
        assert_eq!(patch_origins(21, 8, 4), vec![0, 4, 8, 12, 13]);
        assert_eq!(patch_origins(8, 8, 3), vec![0]);
        assert!(patch_origins(5, 8, 3).is_empty());
    }

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

    /// One pyramid level of a textured pair with a smooth non-rigid motion, for the kernel
    /// tests (8×8 patches, mean normalisation, OpenCV's step).
    struct TestLevel {
        a: Plane,
        ax: Plane,
        ay: Plane,
        bp: Plane,
    }

    impl TestLevel {
        fn new(w: u32, h: u32) -> Self {
            let b = pairs::texture(w, h);
            let a = pairs::make_a(&b, &pairs::smooth_nonrigid(w, h, 3.0)).unwrap();
            let a = Plane::from_gray(&a);
            let (ax, ay) = a.sobel();
            let bp = Plane::from_gray(&b).padded(SEARCH_BORDER);
            Self { a, ax, ay, bp }
        }

        fn ctx(&self) -> LevelCtx<'_> {
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

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_and_baseline_sweeps_agree_bit_for_bit() {
        let Some(avx2) = dynapix_simd::Avx2::detect() else {
            eprintln!("skipping: no AVX2 on this CPU");
            return;
        };
        let (w, h) = (96, 72);
        let level = TestLevel::new(w, h);
        let ctx = level.ctx();
        let xs = patch_origins(w as usize, 8, 3);
        let ys = patch_origins(h as usize, 8, 3);
        let n = xs.len() * ys.len();
        let init: Vec<f32> = (0..n).map(|i| (i % 7) as f32 * 0.3 - 0.9).collect();
        let (mut u1, mut v1) = (init.clone(), init.clone());
        let (mut u2, mut v2) = (init.clone(), init);
        let t = templates(&ctx, &xs, &ys);
        for forward in [true, false] {
            sweep_band_impl(
                None, &ctx, &xs, &ys, 0, &t, &mut u1, &mut v1, forward, 12, true,
            );
            // SAFETY: the token proves the CPU has AVX2.
            unsafe {
                sweep_band_avx2(
                    avx2, &ctx, &xs, &ys, 0, &t, &mut u2, &mut v2, forward, 12, true,
                )
            };
        }
        assert_eq!((u1, v1), (u2, v2));
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn fixed_size_patch_rows_densify_the_same() {
        for (w, h, ps, stride) in [(97, 70, 8, 3), (64, 41, 8, 4), (50, 33, 12, 4)] {
            let level = TestLevel::new(w, h);
            let mut ctx = level.ctx();
            ctx.ps = ps;
            let xs = patch_origins(w as usize, ps, stride);
            let ys = patch_origins(h as usize, ps, stride);
            let n = xs.len() * ys.len();
            let su: Vec<f32> = (0..n)
                .map(|i| ((i * 13) % 29) as f32 * 0.37 - 5.1)
                .collect();
            let sv: Vec<f32> = (0..n).map(|i| ((i * 7) % 23) as f32 * 0.29 - 3.3).collect();
            let (w, h) = (w as usize, h as usize);
            // The reference (baseline build, rows a pixel at a time), the fixed-size rows in
            // the baseline build, and the dispatching build (AVX2 when the CPU has it).
            let planes = || (Plane::zeros(w, h), Plane::zeros(w, h));
            let ((mut u0, mut v0), (mut u1, mut v1), (mut u2, mut v2)) =
                (planes(), planes(), planes());
            densify_rows::<false>(None, &ctx, &xs, &ys, &su, &sv, &mut u0, &mut v0);
            densify_rows::<true>(None, &ctx, &xs, &ys, &su, &sv, &mut u1, &mut v1);
            densify(&ctx, &xs, &ys, &su, &sv, &mut u2, &mut v2);
            let bits = |p: &Plane| p.data.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            for (u, v) in [(&u1, &v1), (&u2, &v2)] {
                assert_eq!(bits(u), bits(&u0), "{w}×{h}, patch {ps}");
                assert_eq!(bits(v), bits(&v0), "{w}×{h}, patch {ps}");
            }
            assert!(u0.data.iter().any(|&x| x != 0.0));
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn four_lane_sums_at_once_equal_one_at_a_time() {
        let Some(avx2) = dynapix_simd::Avx2::detect() else {
            eprintln!("skipping: no AVX2 on this CPU");
            return;
        };
        use std::arch::x86_64::*;
        let cases: [[f32; 8]; 8] = [
            [-0.0; 8],
            [0.0, -0.0, -0.0, -0.0, -0.0, -0.0, -0.0, -0.0],
            [1e8, 1.0, -1e8, 1.0, 3.5e-3, -7.25, 1e-30, 2.0],
            [f32::INFINITY, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0],
            [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8],
            [3.0e7, -1.0, 0.5, -3.0e7, 0.25, 1.0e-7, 7.0, -2.5],
            [f32::NAN, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0],
            [
                1.0,
                f32::INFINITY,
                f32::NEG_INFINITY,
                0.0,
                1.0,
                2.0,
                3.0,
                4.0,
            ],
        ];
        for k in 0..cases.len() {
            let four = [0, 1, 2, 3].map(|i| cases[(k + i) % cases.len()]);
            let want = four.map(|c| sum_in_order(&c));
            // SAFETY: the token proves the CPU has AVX2; each array holds 8 floats.
            let got = unsafe {
                let v = four.map(|c| _mm256_loadu_ps(c.as_ptr()));
                sum_lanes_in_order_4(avx2, v[0], v[1], v[2], v[3])
            };
            assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "{four:?}");
        }
    }

    #[test]
    fn the_inlined_sum_is_the_iterator_sum_bit_for_bit() {
        let cases: [[f32; 8]; 5] = [
            [-0.0; 8],
            [0.0, -0.0, -0.0, -0.0, -0.0, -0.0, -0.0, -0.0],
            [1e8, 1.0, -1e8, 1.0, 3.5e-3, -7.25, 1e-30, 2.0],
            [f32::INFINITY, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0],
            [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8],
        ];
        for c in cases {
            let want: f32 = c.iter().sum();
            assert_eq!(sum_in_order(&c).to_bits(), want.to_bits(), "{c:?}");
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
