//! Single-channel `f32` image planes and the low-level operations DIS needs: 2× box
//! downsampling for the pyramid, Sobel gradients, bilinear sampling with replicated borders,
//! padding with replicated borders and bilinear resizing of flow fields between levels.
//!
//! Everything is row-major and parallelised over rows with rayon; every output element is
//! computed from inputs alone, so the results do not depend on the thread count.

use rayon::prelude::*;

/// Smallest amount of per-pixel work (pixels) worth a rayon task: below it, task overhead
/// dominates (coarse pyramid levels are tiny).
pub(crate) const MIN_PAR_PIXELS: usize = 4096;

/// Minimum number of rows of width `w` per rayon task.
#[inline]
pub(crate) fn min_rows(w: usize) -> usize {
    (MIN_PAR_PIXELS / w.max(1)).max(1)
}

/// Runs `f` compiled for AVX2 when given the token ([`dynapix_simd::Avx2::vectorize`]), else
/// as it is (the baseline build).
///
/// A closure is compiled on its own, without the target features of the function that
/// defines it, so a row closure handed to rayon from a `#[target_feature]` function runs the
/// baseline build (SSE2, four lanes at best). Called inside such a closure, this inlines the
/// closure's body into a function built for AVX2 (eight lanes). Element-wise `f32`
/// arithmetic without fused multiply-add rounds the same in either build, so the results
/// are the same bit for bit; `None` is the reference the tests compare with.
#[inline(always)]
pub(crate) fn simd<R>(isa: Option<dynapix_simd::Avx2>, f: impl FnOnce() -> R) -> R {
    match isa {
        Some(avx2) => avx2.vectorize(f),
        None => f(),
    }
}

/// A row-major single-channel `f32` image.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    /// Width in pixels.
    pub w: usize,
    /// Height in pixels.
    pub h: usize,
    /// `w * h` values, row-major.
    pub data: Vec<f32>,
}

impl Plane {
    /// A plane of zeros.
    pub fn zeros(w: usize, h: usize) -> Self {
        Self {
            w,
            h,
            data: vec![0.0; w * h],
        }
    }

    /// Converts an 8-bit grey image to `f32` intensities in `[0, 255]`.
    pub fn from_gray(img: &image::GrayImage) -> Self {
        Self {
            w: img.width() as usize,
            h: img.height() as usize,
            data: img.as_raw().iter().map(|&p| f32::from(p)).collect(),
        }
    }

    /// Bilinear sample at real coordinates (pixel centres at integers), replicated border.
    #[inline(always)]
    pub fn bilinear(&self, x: f32, y: f32) -> f32 {
        let xm = (self.w - 1) as f32;
        let ym = (self.h - 1) as f32;
        let x = x.clamp(0.0, xm);
        let y = y.clamp(0.0, ym);
        // Clamped to >= 0, so truncation is floor (and much cheaper than `floor` on x86-64).
        let x0 = x as usize;
        let y0 = y as usize;
        let fx = x - x0 as f32;
        let fy = y - y0 as f32;
        let x1 = (x0 + 1).min(self.w - 1);
        let y1 = (y0 + 1).min(self.h - 1);
        let r0 = &self.data[y0 * self.w..(y0 + 1) * self.w];
        let r1 = &self.data[y1 * self.w..(y1 + 1) * self.w];
        let top = r0[x0] + fx * (r0[x1] - r0[x0]);
        let bot = r1[x0] + fx * (r1[x1] - r1[x0]);
        top + fy * (bot - top)
    }

    /// [`Plane::downsample2`] of an 8-bit image, without a full-resolution float copy.
    pub fn downsample2_gray(img: &image::GrayImage) -> Self {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let src = img.as_raw();
        let nw = (w / 2).max(1);
        let nh = (h / 2).max(1);
        let mut out = Plane::zeros(nw, nh);
        if w == 0 || h == 0 {
            return out;
        }
        out.data
            .par_chunks_mut(nw)
            .enumerate()
            .with_min_len(min_rows(nw))
            .for_each(|(y, row)| {
                simd(
                    dynapix_simd::Avx2::detect(),
                    #[inline(always)]
                    || {
                        let y0 = (2 * y).min(h - 1);
                        let y1 = (2 * y + 1).min(h - 1);
                        let r0 = &src[y0 * w..(y0 + 1) * w];
                        let r1 = &src[y1 * w..(y1 + 1) * w];
                        for (x, o) in row.iter_mut().enumerate() {
                            let x0 = (2 * x).min(w - 1);
                            let x1 = (2 * x + 1).min(w - 1);
                            let s = u16::from(r0[x0])
                                + u16::from(r0[x1])
                                + u16::from(r1[x0])
                                + u16::from(r1[x1]);
                            *o = 0.25 * f32::from(s);
                        }
                    },
                );
            });
        out
    }

    /// Halves the resolution by averaging 2×2 blocks (an odd last row/column is dropped, like
    /// an area resize to `w/2 × h/2`). Sizes never go below 1.
    pub fn downsample2(&self) -> Plane {
        let nw = (self.w / 2).max(1);
        let nh = (self.h / 2).max(1);
        let mut out = Plane::zeros(nw, nh);
        out.data
            .par_chunks_mut(nw)
            .enumerate()
            .with_min_len(min_rows(nw))
            .for_each(|(y, row)| {
                simd(
                    dynapix_simd::Avx2::detect(),
                    #[inline(always)]
                    || {
                        let y0 = (2 * y).min(self.h - 1);
                        let y1 = (2 * y + 1).min(self.h - 1);
                        let r0 = &self.data[y0 * self.w..(y0 + 1) * self.w];
                        let r1 = &self.data[y1 * self.w..(y1 + 1) * self.w];
                        for (x, o) in row.iter_mut().enumerate() {
                            let x0 = (2 * x).min(self.w - 1);
                            let x1 = (2 * x + 1).min(self.w - 1);
                            *o = 0.25 * (r0[x0] + r0[x1] + r1[x0] + r1[x1]);
                        }
                    },
                );
            });
        out
    }

    /// Sobel gradients divided by 8, i.e. in intensity units per pixel (replicated border).
    pub fn sobel(&self) -> (Plane, Plane) {
        self.gradients(dynapix_simd::Avx2::detect(), sobel_px, sobel_interior)
    }

    /// Central differences `(f(x+1) - f(x-1)) / 2` (one-sided halves at the border).
    pub fn central_diff(&self) -> (Plane, Plane) {
        self.gradients(dynapix_simd::Avx2::detect(), central_px, central_interior)
    }

    /// Both gradients of every pixel from its 3×3 neighbourhood (replicated border), rows in
    /// parallel: `px` computes pixel x of a row from the rows above, at and below it (`a`,
    /// `b`, `c`); `interior` does the same for pixels 1..w−1 on shifted slices, without
    /// border logic, compiled for AVX2 when given the `isa` token ([`simd`]). Both must be
    /// the same expressions, so every pixel gets the same bits either way.
    #[inline(always)]
    fn gradients(
        &self,
        isa: Option<dynapix_simd::Avx2>,
        px: impl Fn(&[f32], &[f32], &[f32], usize) -> (f32, f32) + Sync,
        interior: impl Fn(&[f32], &[f32], &[f32], &mut [f32], &mut [f32]) + Sync,
    ) -> (Plane, Plane) {
        let (w, h) = (self.w, self.h);
        let mut gx = Plane::zeros(w, h);
        let mut gy = Plane::zeros(w, h);
        if w == 0 {
            return (gx, gy);
        }
        gx.data
            .par_chunks_mut(w)
            .zip(gy.data.par_chunks_mut(w))
            .enumerate()
            .with_min_len(min_rows(w))
            .for_each(|(y, (rx, ry))| {
                let ym = y.saturating_sub(1);
                let yp = (y + 1).min(h - 1);
                let a = &self.data[ym * w..(ym + 1) * w];
                let b = &self.data[y * w..(y + 1) * w];
                let c = &self.data[yp * w..(yp + 1) * w];
                for x in [0, w - 1] {
                    (rx[x], ry[x]) = px(a, b, c, x);
                }
                if w > 2 {
                    simd(
                        isa,
                        #[inline(always)]
                        || interior(a, b, c, &mut rx[1..w - 1], &mut ry[1..w - 1]),
                    );
                }
            });
        (gx, gy)
    }

    /// Vertical central difference only (see [`Plane::central_diff`]).
    pub fn diff_y(&self) -> Plane {
        let (w, h) = (self.w, self.h);
        let mut gy = Plane::zeros(w, h);
        gy.data
            .par_chunks_mut(w)
            .enumerate()
            .with_min_len(min_rows(w))
            .for_each(|(y, ry)| {
                let ym = y.saturating_sub(1);
                let yp = (y + 1).min(h - 1);
                let a = &self.data[ym * w..(ym + 1) * w];
                let c = &self.data[yp * w..(yp + 1) * w];
                for ((o, &top), &bot) in ry.iter_mut().zip(a).zip(c) {
                    *o = 0.5 * (bot - top);
                }
            });
        gy
    }

    /// A copy with `border` replicated pixels on every side (size `(w+2b) × (h+2b)`).
    pub fn padded(&self, border: usize) -> Plane {
        let pw = self.w + 2 * border;
        let ph = self.h + 2 * border;
        let mut out = Plane::zeros(pw, ph);
        out.data
            .par_chunks_mut(pw)
            .enumerate()
            .with_min_len(min_rows(pw))
            .for_each(|(py, row)| {
                let y = (py as isize - border as isize).clamp(0, self.h as isize - 1) as usize;
                let src = &self.data[y * self.w..(y + 1) * self.w];
                let first = src[0];
                let last = src[self.w - 1];
                row[..border].fill(first);
                row[border..border + self.w].copy_from_slice(src);
                row[border + self.w..].fill(last);
            });
        out
    }
}

/// Sobel gradients / 8 of pixel x of row `b` (rows `a` above, `c` below), replicated border.
#[inline(always)]
fn sobel_px(a: &[f32], b: &[f32], c: &[f32], x: usize) -> (f32, f32) {
    let w = b.len();
    let xm = x.saturating_sub(1);
    let xp = (x + 1).min(w - 1);
    let dx = (a[xp] - a[xm]) + 2.0 * (b[xp] - b[xm]) + (c[xp] - c[xm]);
    let dy = (c[xm] - a[xm]) + 2.0 * (c[x] - a[x]) + (c[xp] - a[xp]);
    (dx * 0.125, dy * 0.125)
}

/// [`sobel_px`] of pixels 1..w−1 into `rx`, `ry` (w − 2 values each).
#[inline(always)]
fn sobel_interior(a: &[f32], b: &[f32], c: &[f32], rx: &mut [f32], ry: &mut [f32]) {
    let n = rx.len().min(ry.len());
    let (am, a0, ap) = (&a[..n], &a[1..n + 1], &a[2..n + 2]);
    let (bm, bp) = (&b[..n], &b[2..n + 2]);
    let (cm, c0, cp) = (&c[..n], &c[1..n + 1], &c[2..n + 2]);
    let (rx, ry) = (&mut rx[..n], &mut ry[..n]);
    for i in 0..n {
        let dx = (ap[i] - am[i]) + 2.0 * (bp[i] - bm[i]) + (cp[i] - cm[i]);
        let dy = (cm[i] - am[i]) + 2.0 * (c0[i] - a0[i]) + (cp[i] - ap[i]);
        rx[i] = dx * 0.125;
        ry[i] = dy * 0.125;
    }
}

/// Central differences of pixel x of row `b` (rows `a` above, `c` below), replicated border.
#[inline(always)]
fn central_px(a: &[f32], b: &[f32], c: &[f32], x: usize) -> (f32, f32) {
    let w = b.len();
    let xm = x.saturating_sub(1);
    let xp = (x + 1).min(w - 1);
    (0.5 * (b[xp] - b[xm]), 0.5 * (c[x] - a[x]))
}

/// [`central_px`] of pixels 1..w−1 into `rx`, `ry` (w − 2 values each).
#[inline(always)]
fn central_interior(a: &[f32], b: &[f32], c: &[f32], rx: &mut [f32], ry: &mut [f32]) {
    let n = rx.len().min(ry.len());
    let (a0, c0) = (&a[1..n + 1], &c[1..n + 1]);
    let (bm, bp) = (&b[..n], &b[2..n + 2]);
    let (rx, ry) = (&mut rx[..n], &mut ry[..n]);
    for i in 0..n {
        rx[i] = 0.5 * (bp[i] - bm[i]);
        ry[i] = 0.5 * (c0[i] - a0[i]);
    }
}

/// Source taps `(i0, i1, weight of i1)` of the `n_dst` output samples of a bilinear resize
/// from `n_src` samples with pixel centres aligned (`x_src = (x_dst + 0.5) · s − 0.5`).
fn resize_taps(n_dst: usize, n_src: usize, s: f32) -> Vec<(usize, usize, f32)> {
    (0..n_dst)
        .map(|d| {
            let p = ((d as f32 + 0.5) * s - 0.5).clamp(0.0, (n_src - 1) as f32);
            let i0 = p as usize;
            (i0, (i0 + 1).min(n_src - 1), p - i0 as f32)
        })
        .collect()
}

/// The horizontal half of a separable bilinear flow resize: every source row that an output
/// row reads, interpolated once to the output width (`rows[slot[y]]` holds source row `y`).
/// Each output row then only blends two of these rows. Per pixel this evaluates exactly the
/// expressions of the direct two-dimensional interpolation, so the result has the same bits;
/// a source row is interpolated once instead of once per output row that reads it.
struct ResizeRows {
    /// Output width.
    dw: usize,
    /// Slot of each source row in `u`/`v` (`usize::MAX`: not read).
    slot: Vec<usize>,
    /// Horizontally interpolated u rows, `dw` values per slot.
    u: Vec<f32>,
    /// Horizontally interpolated v rows.
    v: Vec<f32>,
}

impl ResizeRows {
    fn new(u: &Plane, v: &Plane, dw: usize, rows: &[(usize, usize, f32)]) -> Self {
        let cols = resize_taps(dw, u.w, u.w as f32 / dw as f32);
        let mut slot = vec![usize::MAX; u.h];
        let mut used = Vec::new();
        for &(y0, y1, _) in rows {
            for y in [y0, y1] {
                if slot[y] == usize::MAX {
                    slot[y] = used.len();
                    used.push(y);
                }
            }
        }
        let mut hu = vec![0.0f32; used.len() * dw];
        let mut hv = vec![0.0f32; used.len() * dw];
        let sw = u.w;
        hu.par_chunks_mut(dw)
            .zip(hv.par_chunks_mut(dw))
            .zip(used.par_iter())
            .with_min_len(min_rows(dw))
            .for_each(|((ru, rv), &y)| {
                simd(
                    dynapix_simd::Avx2::detect(),
                    #[inline(always)]
                    || {
                        let (su, sv) =
                            (&u.data[y * sw..(y + 1) * sw], &v.data[y * sw..(y + 1) * sw]);
                        for ((pu, pv), &(x0, x1, fx)) in ru.iter_mut().zip(rv.iter_mut()).zip(&cols)
                        {
                            *pu = su[x0] + fx * (su[x1] - su[x0]);
                            *pv = sv[x0] + fx * (sv[x1] - sv[x0]);
                        }
                    },
                );
            });
        Self {
            dw,
            slot,
            u: hu,
            v: hv,
        }
    }

    /// The interpolated u and v rows of source row `y`.
    #[inline]
    fn row(&self, y: usize) -> (&[f32], &[f32]) {
        let o = self.slot[y] * self.dw;
        (&self.u[o..o + self.dw], &self.v[o..o + self.dw])
    }
}

/// Bilinear resize of a flow (u, v planes) to `dw × dh`, scaling vectors by the size ratio.
/// Pixel centres are aligned (`x_src = (x_dst + 0.5) · sw/dw − 0.5`), as in an image resize.
pub fn resize_flow(u: &Plane, v: &Plane, dw: usize, dh: usize) -> (Plane, Plane) {
    let mut ou = Plane::zeros(dw, dh);
    let mut ov = Plane::zeros(dw, dh);
    if dw == 0 || dh == 0 || u.w == 0 || u.h == 0 {
        return (ou, ov);
    }
    let sx = u.w as f32 / dw as f32;
    let sy = u.h as f32 / dh as f32;
    let (scale_u, scale_v) = (1.0 / sx, 1.0 / sy);
    let rows = resize_taps(dh, u.h, sy);
    let h = ResizeRows::new(u, v, dw, &rows);
    ou.data
        .par_chunks_mut(dw)
        .zip(ov.data.par_chunks_mut(dw))
        .zip(rows.par_iter())
        .with_min_len(min_rows(dw))
        .for_each(|((ru, rv), &(y0, y1, fy))| {
            simd(
                dynapix_simd::Avx2::detect(),
                #[inline(always)]
                || {
                    let ((u0, v0), (u1, v1)) = (h.row(y0), h.row(y1));
                    for x in 0..dw {
                        let (tu, bu, tv, bv) = (u0[x], u1[x], v0[x], v1[x]);
                        ru[x] = (tu + fy * (bu - tu)) * scale_u;
                        rv[x] = (tv + fy * (bv - tv)) * scale_v;
                    }
                },
            );
        });
    (ou, ov)
}

/// [`resize_flow`] into interleaved `[u, v]` vectors (the layout of `FlowField`).
pub fn resize_flow_interleaved(u: &Plane, v: &Plane, dw: usize, dh: usize) -> Vec<[f32; 2]> {
    let mut out = vec![[0.0f32; 2]; dw * dh];
    if dw == 0 || dh == 0 || u.w == 0 || u.h == 0 {
        return out;
    }
    let sx = u.w as f32 / dw as f32;
    let sy = u.h as f32 / dh as f32;
    let (scale_u, scale_v) = (1.0 / sx, 1.0 / sy);
    let rows = resize_taps(dh, u.h, sy);
    let h = ResizeRows::new(u, v, dw, &rows);
    out.par_chunks_mut(dw)
        .zip(rows.par_iter())
        .with_min_len(min_rows(dw))
        .for_each(|(row, &(y0, y1, fy))| {
            simd(
                dynapix_simd::Avx2::detect(),
                #[inline(always)]
                || {
                    let ((u0, v0), (u1, v1)) = (h.row(y0), h.row(y1));
                    for (x, o) in row.iter_mut().enumerate() {
                        let (tu, bu, tv, bv) = (u0[x], u1[x], v0[x], v1[x]);
                        *o = [
                            (tu + fy * (bu - tu)) * scale_u,
                            (tv + fy * (bv - tv)) * scale_v,
                        ];
                    }
                },
            );
        });
    out
}

/// Backward warp: `out(x) = src(x + (u, v)(x))`, bilinear with replicated border.
pub fn warp_plane(src: &Plane, u: &Plane, v: &Plane) -> Plane {
    let w = u.w;
    let mut out = Plane::zeros(w, u.h);
    out.data
        .par_chunks_mut(w)
        .enumerate()
        .with_min_len(min_rows(w))
        .for_each(|(y, row)| {
            simd(
                dynapix_simd::Avx2::detect(),
                #[inline(always)]
                || {
                    let o = y * w;
                    for (x, px) in row.iter_mut().enumerate() {
                        *px = src.bilinear(x as f32 + u.data[o + x], y as f32 + v.data[o + x]);
                    }
                },
            );
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize) -> Plane {
        let mut p = Plane::zeros(w, h);
        for y in 0..h {
            for x in 0..w {
                p.data[y * w + x] = 3.0 * x as f32 + 5.0 * y as f32;
            }
        }
        p
    }

    /// The gradients of pixel x of row b, from the rows around it.
    type PixelGradient = fn(&[f32], &[f32], &[f32], usize) -> (f32, f32);

    #[test]
    fn gradients_equal_their_per_pixel_definitions() {
        for (w, h) in [(1, 1), (2, 3), (3, 2), (9, 7), (33, 5)] {
            let mut p = Plane::zeros(w, h);
            for (i, x) in p.data.iter_mut().enumerate() {
                *x = ((i * 37) % 101) as f32 * 1.7 - 40.0 + (i as f32 * 0.3).sin();
            }
            let px_all = |f: PixelGradient| {
                let (mut gx, mut gy) = (Plane::zeros(w, h), Plane::zeros(w, h));
                for y in 0..h {
                    let row = |r: usize| &p.data[r * w..(r + 1) * w];
                    let (a, b, c) = (row(y.saturating_sub(1)), row(y), row((y + 1).min(h - 1)));
                    for x in 0..w {
                        (gx.data[y * w + x], gy.data[y * w + x]) = f(a, b, c, x);
                    }
                }
                (gx, gy)
            };
            let bits = |a: &Plane| a.data.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            for (got, want) in [
                (p.sobel(), px_all(sobel_px)),
                (p.central_diff(), px_all(central_px)),
                (
                    p.gradients(None, sobel_px, sobel_interior),
                    px_all(sobel_px),
                ),
            ] {
                assert_eq!(bits(&got.0), bits(&want.0), "{w}×{h}");
                assert_eq!(bits(&got.1), bits(&want.1), "{w}×{h}");
            }
        }
    }

    #[test]
    fn sobel_and_central_diff_recover_ramp_slope() {
        let p = ramp(9, 7);
        let (gx, gy) = p.sobel();
        let (cx, cy) = p.central_diff();
        let i = 3 * 9 + 4;
        assert!((gx.data[i] - 3.0).abs() < 1e-5 && (gy.data[i] - 5.0).abs() < 1e-5);
        assert!((cx.data[i] - 3.0).abs() < 1e-5 && (cy.data[i] - 5.0).abs() < 1e-5);
    }

    #[test]
    fn bilinear_interpolates_and_clamps() {
        let p = ramp(4, 3);
        assert!((p.bilinear(1.5, 0.25) - (4.5 + 1.25)).abs() < 1e-5);
        assert_eq!(p.bilinear(-3.0, -2.0), 0.0);
        assert_eq!(p.bilinear(10.0, 10.0), 9.0 + 10.0);
    }

    #[test]
    fn padding_replicates_and_downsample_averages() {
        let p = ramp(4, 2);
        let q = p.padded(2);
        assert_eq!((q.w, q.h), (8, 6));
        assert_eq!(q.data[0], p.data[0]);
        assert_eq!(q.data[5 * 8 + 7], p.data[7]);
        let d = p.downsample2();
        assert_eq!((d.w, d.h), (2, 1));
        assert!((d.data[0] - (0.0 + 3.0 + 5.0 + 8.0) / 4.0).abs() < 1e-6);
    }

    // The direct two-dimensional interpolation the separable resize replaced, kept as the
    // reference it must equal bit for bit (the interleaved version computed the same values).
    /// Bilinear resize of a flow (u, v planes) to `dw × dh`, scaling vectors by the size ratio.
    /// Pixel centres are aligned (`x_src = (x_dst + 0.5) · sw/dw − 0.5`), as in an image resize.
    fn resize_flow_direct(u: &Plane, v: &Plane, dw: usize, dh: usize) -> (Plane, Plane) {
        let sx = u.w as f32 / dw as f32;
        let sy = u.h as f32 / dh as f32;
        let (scale_u, scale_v) = (1.0 / sx, 1.0 / sy);
        // The taps are unchanged by the separable version: shared with it.
        let cols = resize_taps(dw, u.w, sx);
        let rows = resize_taps(dh, u.h, sy);
        let mut ou = Plane::zeros(dw, dh);
        let mut ov = Plane::zeros(dw, dh);
        let sw = u.w;
        ou.data
            .par_chunks_mut(dw)
            .zip(ov.data.par_chunks_mut(dw))
            .zip(rows.par_iter())
            .with_min_len(min_rows(dw))
            .for_each(|((ru, rv), &(y0, y1, fy))| {
                let (u0, u1) = (
                    &u.data[y0 * sw..(y0 + 1) * sw],
                    &u.data[y1 * sw..(y1 + 1) * sw],
                );
                let (v0, v1) = (
                    &v.data[y0 * sw..(y0 + 1) * sw],
                    &v.data[y1 * sw..(y1 + 1) * sw],
                );
                for ((pu, pv), &(x0, x1, fx)) in ru.iter_mut().zip(rv.iter_mut()).zip(&cols) {
                    let tu = u0[x0] + fx * (u0[x1] - u0[x0]);
                    let bu = u1[x0] + fx * (u1[x1] - u1[x0]);
                    let tv = v0[x0] + fx * (v0[x1] - v0[x0]);
                    let bv = v1[x0] + fx * (v1[x1] - v1[x0]);
                    *pu = (tu + fy * (bu - tu)) * scale_u;
                    *pv = (tv + fy * (bv - tv)) * scale_v;
                }
            });
        (ou, ov)
    }

    #[test]
    fn the_separable_resize_equals_the_direct_one_bit_for_bit() {
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 40.0
        };
        for (sw, sh, dw, dh) in [
            (160, 120, 640, 480),
            (40, 30, 80, 60),
            (41, 31, 83, 61),
            (7, 5, 640, 3),
            (80, 60, 33, 17),
            (1, 1, 5, 4),
            (3, 9, 1, 1),
        ] {
            let mut u = Plane::zeros(sw, sh);
            let mut v = Plane::zeros(sw, sh);
            u.data.iter_mut().for_each(|x| *x = rnd());
            v.data.iter_mut().for_each(|x| *x = rnd());
            let (ru, rv) = resize_flow(&u, &v, dw, dh);
            let (eu, ev) = resize_flow_direct(&u, &v, dw, dh);
            let bits = |p: &Plane| p.data.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&ru), bits(&eu), "u, {sw}×{sh} → {dw}×{dh}");
            assert_eq!(bits(&rv), bits(&ev), "v, {sw}×{sh} → {dw}×{dh}");
            let inter = resize_flow_interleaved(&u, &v, dw, dh);
            // The interleaved layout holds the direct planes' values, pixel by pixel.
            let direct: Vec<u32> = (eu.data.iter().zip(&ev.data))
                .flat_map(|(a, b)| [a.to_bits(), b.to_bits()])
                .collect();
            let flat: Vec<u32> = inter.iter().flatten().map(|x| x.to_bits()).collect();
            assert_eq!(flat, direct, "interleaved, {sw}×{sh} → {dw}×{dh}");
        }
    }

    #[test]
    fn resize_flow_scales_vectors() {
        let u = Plane {
            w: 2,
            h: 2,
            data: vec![1.0; 4],
        };
        let v = Plane {
            w: 2,
            h: 2,
            data: vec![-2.0; 4],
        };
        let (ru, rv) = resize_flow(&u, &v, 4, 4);
        assert!(ru.data.iter().all(|&a| (a - 2.0).abs() < 1e-6));
        assert!(rv.data.iter().all(|&a| (a + 4.0).abs() < 1e-6));
    }
}
