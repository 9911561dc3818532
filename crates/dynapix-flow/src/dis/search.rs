//! The inverse search (step 2 of DIS): patch evaluation, Gauss-Newton descent and the
//! propagating sweeps over bands of patch rows.

use super::SEARCH_BORDER;
use super::patch::{LevelCtx, Template, clamp_disp};
use super::sums::{patch_sums, patch_sums_8_avx, patch_sums_8_sse, patch_sums_dyn};

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
pub(super) fn sweep_band(
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dis::{fixtures::*, *};

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
}
