//! Densification (step 3 of DIS, paper §2.2): every pixel averages the displacements of the
//! patches that cover it, weighted by the photometric error.

use super::SEARCH_BORDER;
use super::patch::LevelCtx;
use crate::plane::{Plane, min_rows, simd};
use rayon::prelude::*;

/// Dense flow as the photometrically weighted average of the covering patches (paper §2.2),
/// compiled for AVX2 when the CPU has it, with patch rows of 8 pixels as whole vectors. Every
/// build does the same operations per pixel in the same order (no fused multiply-add), so the
/// results are identical (test `fixed_size_patch_rows_densify_the_same`).
pub(super) fn densify(
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
#[allow(clippy::too_many_arguments)]
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
    use crate::dis::{fixtures::*, *};

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
}
