//! Small 8-bit image operations the ORB extractor needs, written to follow OpenCV's integer
//! arithmetic as used by ORB-SLAM2 (`resize` with `INTER_LINEAR`, `GaussianBlur` 7×7 σ = 2 with
//! `BORDER_REFLECT_101`, `fastAtan2`, `cvtColor` RGB→GRAY), so that pyramid levels, angles and
//! descriptors are close to the reference (spec §6.2).

/// A row-major 8-bit single-channel image.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Plane {
    pub w: usize,
    pub h: usize,
    pub data: Vec<u8>,
}

impl Plane {
    /// Pixel at (x, y); callers guarantee the coordinates are inside.
    #[inline(always)]
    pub fn at(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.w + x]
    }
}

/// OpenCV's fixed-point scale of the bilinear interpolation weights (`INTER_RESIZE_COEF_BITS`).
const RESIZE_COEF_BITS: u32 = 11;
const RESIZE_COEF_SCALE: f32 = (1 << RESIZE_COEF_BITS) as f32;

/// Source index and fixed-point weights of every destination coordinate, as OpenCV's
/// `resizeGeneric_` computes them for `INTER_LINEAR` (half-pixel centres, clamped at the edges).
fn linear_taps(src: usize, dst: usize) -> Vec<(usize, i32, i32)> {
    let scale = 1.0 / (dst as f64 / src as f64);
    (0..dst)
        .map(|d| {
            let mut f = ((d as f64 + 0.5) * scale - 0.5) as f32;
            let mut s = f.floor() as i64;
            f -= s as f32;
            if s < 0 {
                f = 0.0;
                s = 0;
            }
            if s >= src as i64 - 1 {
                f = 0.0;
                s = src as i64 - 1;
            }
            let a0 = ((1.0 - f) * RESIZE_COEF_SCALE).round_ties_even() as i32;
            let a1 = (1 << RESIZE_COEF_BITS) - a0;
            (s.max(0) as usize, a0, a1)
        })
        .collect()
}

/// [`linear_taps`] of a row as separate arrays, with the second source pixel clamped into
/// the row: where the clamp applies its weight is 0 ([`linear_taps`] gives `a1 = 0` at the
/// last pixel), so the blend is the same without a branch per pixel.
struct HorizontalTaps {
    /// Width of the source row: every index below is smaller.
    src: usize,
    s0: Vec<usize>,
    s1: Vec<usize>,
    a0: Vec<i32>,
    a1: Vec<i32>,
}

impl HorizontalTaps {
    fn new(src: usize, dst: usize) -> Self {
        let taps = linear_taps(src, dst);
        let last = src.saturating_sub(1);
        Self {
            src,
            s0: taps.iter().map(|t| t.0).collect(),
            s1: taps.iter().map(|t| (t.0 + 1).min(last)).collect(),
            a0: taps.iter().map(|t| t.1).collect(),
            a1: taps.iter().map(|t| t.2).collect(),
        }
    }

    /// The horizontal pass of one source row into `out` (one value per destination pixel).
    #[inline(always)]
    fn apply(&self, row: &[u8], out: &mut [i32]) {
        let n = out.len().min(self.s0.len());
        let (s0, s1, a0, a1) = (&self.s0[..n], &self.s1[..n], &self.a0[..n], &self.a1[..n]);
        let out = &mut out[..n];
        if self.src == 0 || self.src > row.len() {
            // Not a row of the image the taps were made for: out-of-row pixels read 0.
            for i in 0..n {
                let p0 = row.get(s0[i]).copied().unwrap_or(0) as i32;
                let p1 = row.get(s1[i]).copied().unwrap_or(0) as i32;
                out[i] = p0 * a0[i] + p1 * a1[i];
            }
            return;
        }
        for i in 0..n {
            // SAFETY: every tap indexes a pixel below `self.src` (see `new`), and the row
            // holds at least `self.src` pixels, checked above.
            let (p0, p1) = unsafe {
                (
                    *row.get_unchecked(s0[i]) as i32,
                    *row.get_unchecked(s1[i]) as i32,
                )
            };
            out[i] = p0 * a0[i] + p1 * a1[i];
        }
    }
}

/// Bilinear downscale of `src` to `w × h` with OpenCV's fixed-point `INTER_LINEAR` arithmetic,
/// compiled for AVX2 when the CPU has it (integer arithmetic: the same result in every build,
/// test `resize_dispatch_equals_the_baseline_build`).
pub(crate) fn resize_linear(src: &Plane, w: usize, h: usize) -> Plane {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return unsafe { resize_linear_avx2(avx2, src, w, h) };
    }
    resize_linear_body(src, w, h)
}

/// [`resize_linear_body`] compiled for AVX2 (eight 32-bit multiplies per instruction in the
/// vertical blend; the baseline SSE2 build has no 32-bit vector multiply).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn resize_linear_avx2(_: dynapix_simd::Avx2, src: &Plane, w: usize, h: usize) -> Plane {
    resize_linear_body(src, w, h)
}

#[inline(always)]
fn resize_linear_body(src: &Plane, w: usize, h: usize) -> Plane {
    if w == 0 || h == 0 || src.w == 0 || src.h == 0 {
        return Plane {
            w,
            h,
            data: vec![0; w * h],
        };
    }
    let xt = HorizontalTaps::new(src.w, w);
    let yt = linear_taps(src.h, h);
    // Horizontal pass per needed source row (values scaled by 2^11) into two row buffers
    // reused from row to row, then the vertical blend.
    let mut data = vec![0u8; w * h];
    let (mut r0, mut r1) = (vec![0i32; w], vec![0i32; w]);
    // The source rows held by r0 and r1.
    let mut held: Option<usize> = None;
    for (dy, &(sy, b0, b1)) in yt.iter().enumerate() {
        let sy1 = (sy + 1).min(src.h - 1);
        let row = |y: usize| &src.data[y * src.w..(y + 1) * src.w];
        match held {
            Some(c) if c == sy => {}
            Some(c) if c + 1 == sy => {
                std::mem::swap(&mut r0, &mut r1);
                xt.apply(row(sy1), &mut r1);
            }
            _ => {
                xt.apply(row(sy), &mut r0);
                xt.apply(row(sy1), &mut r1);
            }
        }
        held = Some(sy);
        let out = &mut data[dy * w..(dy + 1) * w];
        for ((o, &p0), &p1) in out.iter_mut().zip(&r0).zip(&r1) {
            let v = ((b0 * (p0 >> 4)) >> 16) + ((b1 * (p1 >> 4)) >> 16) + 2;
            *o = (v >> 2).clamp(0, 255) as u8;
        }
    }
    Plane { w, h, data }
}

/// Reflect-101 index (`gfedcb|abcdefgh|gfedcba`) for a coordinate that may lie outside `[0, n)`.
#[inline(always)]
fn reflect101(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let n = n as isize;
    let mut i = i;
    while i < 0 || i >= n {
        if i < 0 {
            i = -i;
        }
        if i >= n {
            i = 2 * n - 2 - i;
        }
    }
    i as usize
}

/// Gaussian kernel of `2·radius+1` taps for σ in 8-bit fixed point (sum exactly 256), quantised
/// as OpenCV's bit-exact 8-bit smoothing does (`getGaussianKernelFixedPoint_ED`): outer taps
/// rounded with error diffusion towards the centre, the centre tap takes the remainder.
fn gaussian_kernel_q8(radius: usize, sigma: f64) -> Vec<i32> {
    let raw: Vec<f64> = (0..=2 * radius)
        .map(|i| {
            let x = i as f64 - radius as f64;
            (-(x * x) / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let sum: f64 = raw.iter().sum();
    let mut k = vec![0i32; 2 * radius + 1];
    let mut err = 0.0f64;
    let mut total = 0i32;
    for i in 0..radius {
        let adj = raw[i] / sum * 256.0 + err;
        let v = adj.round_ties_even();
        err = adj - v;
        k[i] = v as i32;
        k[2 * radius - i] = v as i32;
        total += 2 * v as i32;
    }
    k[radius] = 256 - total;
    k
}

/// Separable Gaussian blur (window `2·radius+1`, `sigma`) with reflect-101 borders, in 8.8
/// fixed point per pass and rounding at the end (as OpenCV's 8-bit smoothing).
pub(crate) fn gaussian_blur(src: &Plane, radius: usize, sigma: f64) -> Plane {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return unsafe { gaussian_blur_avx2(avx2, src, radius, sigma) };
    }
    gaussian_blur_body(src, radius, sigma)
}

/// [`gaussian_blur_body`] compiled for AVX2 (twice the lanes of the integer passes; the
/// same integer arithmetic, so the same result).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn gaussian_blur_avx2(_: dynapix_simd::Avx2, src: &Plane, radius: usize, sigma: f64) -> Plane {
    gaussian_blur_body(src, radius, sigma)
}

#[inline(always)]
#[allow(clippy::needless_range_loop)] // indexed loops vectorise here, zipped iterators did not
fn gaussian_blur_body(src: &Plane, radius: usize, sigma: f64) -> Plane {
    let (w, h) = (src.w, src.h);
    if w == 0 || h == 0 {
        return src.clone();
    }
    let k = gaussian_kernel_q8(radius, sigma);
    let taps = 2 * radius + 1;
    // Horizontal pass into u16 (≤ 255·256 fits), on a row padded by reflection so the inner
    // loop has no border logic and vectorises.
    let mut tmp = vec![0u16; w * h];
    let mut padded = vec![0u8; w + 2 * radius];
    for y in 0..h {
        let row = &src.data[y * w..(y + 1) * w];
        padded[radius..radius + w].copy_from_slice(row);
        for i in 0..radius {
            padded[i] = row[reflect101(i as isize - radius as isize, w)];
            padded[radius + w + i] = row[reflect101((w + i) as isize, w)];
        }
        let out = &mut tmp[y * w..(y + 1) * w];
        if radius == 3 {
            hpass7(&padded, out, [k[0], k[1], k[2], k[3]]);
            continue;
        }
        // Symmetric kernel: pair taps t and 2r−t to halve the multiplications.
        let kc = k[radius] as u16;
        let mid = &padded[radius..radius + w];
        for i in 0..w {
            out[i] = kc * mid[i] as u16;
        }
        for t in 0..radius {
            let kv = k[t] as u16;
            let l = &padded[t..t + w];
            let r = &padded[2 * radius - t..2 * radius - t + w];
            for i in 0..w {
                out[i] += kv * (l[i] as u16 + r[i] as u16);
            }
        }
    }
    // Vertical pass, 16 fractional bits, rounded.
    let mut data = vec![0u8; w * h];
    let mut acc = vec![0u32; w];
    for y in 0..h {
        let row = |t: usize| {
            let sy = reflect101(y as isize + t as isize - radius as isize, h);
            &tmp[sy * w..(sy + 1) * w]
        };
        let out = &mut data[y * w..(y + 1) * w];
        if radius == 3 {
            let rows = [row(0), row(1), row(2), row(3), row(4), row(5), row(6)];
            vpass7(rows, out, [k[0], k[1], k[2], k[3]]);
            continue;
        }
        acc.fill(1 << 15);
        let kc = k[radius] as u32;
        let c = row(radius);
        for i in 0..w {
            acc[i] += kc * c[i] as u32;
        }
        for t in 0..radius {
            let kv = k[t] as u32;
            let (l, r) = (row(t), row(taps - 1 - t));
            for i in 0..w {
                acc[i] += kv * (l[i] as u32 + r[i] as u32);
            }
        }
        for (o, &a) in out.iter_mut().zip(&acc) {
            *o = (a >> 16).min(255) as u8;
        }
    }
    Plane { w, h, data }
}

/// Horizontal 7-tap symmetric pass of one padded row (`padded.len() = out.len() + 6`), all taps
/// in one expression per pixel so that it vectorises.
#[inline(always)]
fn hpass7(padded: &[u8], out: &mut [u16], k: [i32; 4]) {
    let w = out.len();
    let (k0, k1, k2, k3) = (k[0] as u16, k[1] as u16, k[2] as u16, k[3] as u16);
    let (p0, p1, p2, p3) = (
        &padded[0..w],
        &padded[1..1 + w],
        &padded[2..2 + w],
        &padded[3..3 + w],
    );
    let (p4, p5, p6) = (&padded[4..4 + w], &padded[5..5 + w], &padded[6..6 + w]);
    for (i, o) in out.iter_mut().enumerate() {
        *o = k3 * p3[i] as u16
            + k0 * (p0[i] as u16 + p6[i] as u16)
            + k1 * (p1[i] as u16 + p5[i] as u16)
            + k2 * (p2[i] as u16 + p4[i] as u16);
    }
}

/// Vertical 7-tap symmetric pass over seven 8.8 fixed-point rows, rounded to 8 bits. Inlined,
/// so it is compiled with the caller's target features (AVX2 in [`gaussian_blur`]).
#[inline(always)]
fn vpass7(r: [&[u16]; 7], out: &mut [u8], k: [i32; 4]) {
    let w = out.len();
    let (k0, k1, k2, k3) = (k[0] as u32, k[1] as u32, k[2] as u32, k[3] as u32);
    let (r0, r1, r2, r3) = (&r[0][..w], &r[1][..w], &r[2][..w], &r[3][..w]);
    let (r4, r5, r6) = (&r[4][..w], &r[5][..w], &r[6][..w]);
    for (i, o) in out.iter_mut().enumerate() {
        let a = k3 * r3[i] as u32
            + k0 * (r0[i] as u32 + r6[i] as u32)
            + k1 * (r1[i] as u32 + r5[i] as u32)
            + k2 * (r2[i] as u32 + r4[i] as u32)
            + (1 << 15);
        *o = (a >> 16).min(255) as u8;
    }
}

/// OpenCV's `fastAtan2`: a polynomial approximation of atan2 in degrees, range [0, 360),
/// accuracy about 0.3°. ORB-SLAM2 stores keypoint angles computed with it.
pub(crate) fn fast_atan2_deg(y: f32, x: f32) -> f32 {
    const R2D: f32 = 180.0 / std::f32::consts::PI;
    const P1: f32 = 0.999_787_84 * R2D;
    const P3: f32 = -0.325_808_4 * R2D;
    const P5: f32 = 0.155_578_65 * R2D;
    const P7: f32 = -0.044_326_555 * R2D;
    let (ax, ay) = (x.abs(), y.abs());
    let eps = f64::EPSILON;
    let mut a = if ax >= ay {
        let c = (ay as f64 / (ax as f64 + eps)) as f32;
        let c2 = c * c;
        (((P7 * c2 + P5) * c2 + P3) * c2 + P1) * c
    } else {
        let c = (ax as f64 / (ay as f64 + eps)) as f32;
        let c2 = c * c;
        90.0 - (((P7 * c2 + P5) * c2 + P3) * c2 + P1) * c
    };
    if x < 0.0 {
        a = 180.0 - a;
    }
    if y < 0.0 {
        a = 360.0 - a;
    }
    if a >= 360.0 { a - 360.0 } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resize_of_constant_image_is_constant() {
        let p = Plane {
            w: 64,
            h: 48,
            data: vec![137; 64 * 48],
        };
        let r = resize_linear(&p, 53, 40);
        assert_eq!((r.w, r.h), (53, 40));
        assert!(r.data.iter().all(|&v| v == 137));
    }

    #[test]
    fn resize_of_ramp_interpolates() {
        // A horizontal ramp 0, 10, 20, ... resized by 1/2 lands between source samples.
        let w = 20;
        let p = Plane {
            w,
            h: 2,
            data: (0..2 * w).map(|i| ((i % w) * 10) as u8).collect(),
        };
        let r = resize_linear(&p, 10, 1);
        // Destination x maps to source 2x + 0.5 → value 20x + 5.
        for x in 0..9 {
            assert_eq!(r.data[x] as usize, 20 * x + 5, "x={x}");
        }
    }

    #[test]
    fn blur_kernel_sums_to_256_and_keeps_constants() {
        let k = gaussian_kernel_q8(3, 2.0);
        assert_eq!(k.iter().sum::<i32>(), 256);
        // 256 · [0.0702, 0.1311, 0.1907, 0.2161]: 17.96, 33.56, 48.82 with error diffusion.
        assert_eq!(k, vec![18, 34, 48, 56, 48, 34, 18]);
        assert!(k.windows(2).take(3).all(|w| w[0] <= w[1]));
        let p = Plane {
            w: 9,
            h: 5,
            data: vec![200; 45],
        };
        assert!(gaussian_blur(&p, 3, 2.0).data.iter().all(|&v| v == 200));
    }

    #[test]
    fn blur_spreads_an_impulse_symmetrically() {
        let mut p = Plane {
            w: 15,
            h: 15,
            data: vec![0; 225],
        };
        p.data[7 * 15 + 7] = 255;
        let b = gaussian_blur(&p, 3, 2.0);
        assert_eq!(b.at(6, 7), b.at(8, 7));
        assert_eq!(b.at(7, 5), b.at(7, 9));
        assert!(b.at(7, 7) > b.at(6, 7) && b.at(6, 7) > b.at(5, 7));
        assert_eq!(b.at(0, 0), 0);
    }

    #[test]
    fn blur_dispatch_equals_the_baseline_build() {
        for (w, h, radius) in [(37usize, 23usize, 3usize), (64, 48, 2), (9, 40, 1)] {
            let data: Vec<u8> = (0..w * h)
                .map(|i| ((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 56) as u8)
                .collect();
            let p = Plane { w, h, data };
            assert_eq!(
                gaussian_blur(&p, radius, 2.0).data,
                gaussian_blur_body(&p, radius, 2.0).data
            );
        }
    }

    #[test]
    fn resize_dispatch_equals_the_baseline_build() {
        for (w, h, dw, dh) in [
            (640usize, 480usize, 533usize, 400usize),
            (37, 23, 30, 19),
            (9, 40, 7, 33),
        ] {
            let data: Vec<u8> = (0..w * h)
                .map(|i| ((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 56) as u8)
                .collect();
            let p = Plane { w, h, data };
            assert_eq!(
                resize_linear(&p, dw, dh).data,
                resize_linear_body(&p, dw, dh).data
            );
        }
    }

    #[test]
    fn fast_atan2_close_to_atan2() {
        for i in 0..720 {
            let t = (i as f32) * 0.5_f32.to_radians() + 0.001;
            let (y, x) = (t.sin() * 100.0, t.cos() * 100.0);
            let exact = y.atan2(x).to_degrees().rem_euclid(360.0);
            let got = fast_atan2_deg(y, x);
            let diff = (got - exact).abs();
            assert!(
                diff.min(360.0 - diff) < 0.05,
                "t={t} exact={exact} got={got}"
            );
        }
        assert_eq!(fast_atan2_deg(0.0, 0.0), 0.0);
    }
}
