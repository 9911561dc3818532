//! The patch grid of a pyramid level and the per-patch template (gradients, inverse
//! Hessian) that the inverse search reuses at every iteration.

use super::{MIN_HESSIAN_DET, SEARCH_BORDER};
use crate::plane::{Plane, min_rows};
use rayon::prelude::*;

/// Patch origins along one axis: every `stride`, plus one aligned to the far border.
pub(super) fn patch_origins(len: usize, ps: usize, stride: usize) -> Vec<usize> {
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
pub(super) struct LevelCtx<'a> {
    pub(super) a: &'a Plane,
    pub(super) ax: &'a Plane,
    pub(super) ay: &'a Plane,
    /// Image B padded by `SEARCH_BORDER`.
    pub(super) bp: &'a Plane,
    pub(super) ps: usize,
    pub(super) mean_norm: bool,
    /// Fraction of the Gauss-Newton step taken per iteration.
    pub(super) step: f32,
}

/// What the descent needs about one patch of A: the inverse of its (mean-normalised)
/// Hessian and the sums of its gradients (for the mean-normalisation correction).
#[derive(Clone, Copy)]
pub(super) struct Template {
    pub(super) hinv: [f32; 3],
    pub(super) sum_gx: f32,
    pub(super) sum_gy: f32,
    /// False for textureless patches: they take part in propagation but do not descend.
    pub(super) textured: bool,
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
pub(super) fn templates(ctx: &LevelCtx, xs: &[usize], ys: &[usize]) -> Vec<Template> {
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
pub(super) fn clamp_disp(ctx: &LevelCtx, px: usize, py: usize, u: f32, v: f32) -> (f32, f32) {
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
}
