//! The sums of one patch comparison (Σd, Σd², Σd·∇A) at a sub-pixel displacement: generic,
//! SSE2 and AVX2 versions, all in the same order so the same bits.

use super::patch::LevelCtx;

/// Raw sums over the patch of the residual `d = B(x+u) − A(x)`: Σd, Σd², Σd·Ax, Σd·Ay.
/// All pixels of a patch share the bilinear weights; with a compile-time patch width the
/// per-lane accumulators vectorise.
#[inline(always)]
pub(super) fn patch_sums<const N: usize>(
    ctx: &LevelCtx,
    px: usize,
    py: usize,
    x: f32,
    y: f32,
) -> [f32; 4] {
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
pub(super) fn patch_sums_8_sse(ctx: &LevelCtx, px: usize, py: usize, x: f32, y: f32) -> [f32; 4] {
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
pub(super) fn patch_sums_8_avx(
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
pub(super) fn patch_sums_dyn(ctx: &LevelCtx, px: usize, py: usize, x: f32, y: f32) -> [f32; 4] {
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
