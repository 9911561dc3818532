//! Variational refinement of a dense flow (Kroeger et al., ECCV 2016, §2.3; the energy of
//! Brox et al. 2004 as used by DIS and by OpenCV's `VariationalRefinement`).
//!
//! Energy over the flow increment `dw = (du, dv)` around the current flow `w`:
//! `E = δ Ψ(E_I) + γ Ψ(E_G) + α Ψ(|∇(w + dw)|²)` with the robust `Ψ(s²) = sqrt(s² + ε²)`,
//! a brightness constancy term `E_I` and a gradient constancy term `E_G`, both linearised
//! around `I1` warped by `w` and normalised by the local gradient magnitude (`+ ζ²`).
//! Outer fixed-point iterations freeze the robust weights; inner red-black SOR iterations
//! solve the resulting linear system. Red-black ordering makes each half-sweep independent
//! per pixel, so the row-parallel sweeps give the same result for any thread count.

use crate::plane::{MIN_PAR_PIXELS, Plane, min_rows, simd, warp_plane};
use rayon::prelude::*;

/// Parameters of the variational refinement (defaults = OpenCV's DIS/VariationalRefinement).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct VariationalParams {
    /// Outer fixed-point iterations (0 disables the refinement).
    pub fixed_point_iterations: usize,
    /// Inner SOR iterations per fixed-point iteration.
    pub sor_iterations: usize,
    /// SOR relaxation factor.
    pub omega: f32,
    /// Weight of the smoothness term.
    pub alpha: f32,
    /// Weight of the brightness constancy term.
    pub delta: f32,
    /// Weight of the gradient constancy term.
    pub gamma: f32,
    /// Regulariser of the gradient normalisation and of the diagonal.
    pub zeta: f32,
    /// ε of the robust penaliser.
    pub epsilon: f32,
}

impl Default for VariationalParams {
    fn default() -> Self {
        Self {
            fixed_point_iterations: 5,
            sor_iterations: 5,
            omega: 1.6,
            alpha: 20.0,
            delta: 5.0,
            gamma: 10.0,
            zeta: 0.1,
            epsilon: 0.001,
        }
    }
}

/// Data-term coefficients at one level, normalised by the local gradient magnitude
/// (`+ ζ²`), so the fixed-point iterations need no division by the normalisers.
struct DataCoeffs {
    /// Brightness constancy: (Ix, Iy, Iz) / sqrt(Ix² + Iy² + ζ²).
    bx: Vec<f32>,
    by: Vec<f32>,
    bz: Vec<f32>,
    /// Constancy of the x gradient: (Ixx, Ixy, Ixz) / sqrt(Ixx² + Ixy² + ζ²).
    gxx: Vec<f32>,
    gxy: Vec<f32>,
    gxz: Vec<f32>,
    /// Constancy of the y gradient: (Ixy, Iyy, Iyz) / sqrt(Iyy² + Ixy² + ζ²).
    gyx: Vec<f32>,
    gyy: Vec<f32>,
    gyz: Vec<f32>,
}

#[inline(always)]
fn data_coeffs(i0: &Plane, warped: Plane, zeta: f32) -> DataCoeffs {
    let (w, h) = (i0.w, i0.h);
    // Spatial derivatives on the average of both images make the linearisation symmetric;
    // the warped image is turned into that average in place.
    let mut avg = warped;
    let mut iz = Plane::zeros(w, h);
    avg.data
        .par_iter_mut()
        .zip(iz.data.par_iter_mut())
        .zip(i0.data.par_iter())
        .with_min_len(MIN_PAR_PIXELS)
        .for_each(|((a, z), &p0)| {
            let p1 = *a;
            *a = 0.5 * (p0 + p1);
            *z = p1 - p0;
        });
    // True derivatives (OpenCV's [-1, 0, 1] kernel doubles them; that measured worse here).
    let (ix, iy) = avg.central_diff();
    let (ixz, iyz) = iz.central_diff();
    let (ixx, ixy) = ix.central_diff();
    let iyy = iy.diff_y();
    let n = w * h;
    let mut c = DataCoeffs {
        bx: vec![0.0; n],
        by: vec![0.0; n],
        bz: vec![0.0; n],
        gxx: vec![0.0; n],
        gxy: vec![0.0; n],
        gxz: vec![0.0; n],
        gyx: vec![0.0; n],
        gyy: vec![0.0; n],
        gyz: vec![0.0; n],
    };
    let z2 = zeta * zeta;
    c.bx.par_iter_mut()
        .zip(c.by.par_iter_mut())
        .zip(c.bz.par_iter_mut())
        .enumerate()
        .with_min_len(MIN_PAR_PIXELS)
        .for_each(|(i, ((bx, by), bz))| {
            let r = 1.0 / (ix.data[i] * ix.data[i] + iy.data[i] * iy.data[i] + z2).sqrt();
            *bx = ix.data[i] * r;
            *by = iy.data[i] * r;
            *bz = iz.data[i] * r;
        });
    c.gxx
        .par_iter_mut()
        .zip(c.gxy.par_iter_mut())
        .zip(c.gxz.par_iter_mut())
        .enumerate()
        .with_min_len(MIN_PAR_PIXELS)
        .for_each(|(i, ((a, b), z))| {
            let r = 1.0 / (ixx.data[i] * ixx.data[i] + ixy.data[i] * ixy.data[i] + z2).sqrt();
            *a = ixx.data[i] * r;
            *b = ixy.data[i] * r;
            *z = ixz.data[i] * r;
        });
    c.gyx
        .par_iter_mut()
        .zip(c.gyy.par_iter_mut())
        .zip(c.gyz.par_iter_mut())
        .enumerate()
        .with_min_len(MIN_PAR_PIXELS)
        .for_each(|(i, ((a, b), z))| {
            let r = 1.0 / (iyy.data[i] * iyy.data[i] + ixy.data[i] * ixy.data[i] + z2).sqrt();
            *a = ixy.data[i] * r;
            *b = iyy.data[i] * r;
            *z = iyz.data[i] * r;
        });
    c
}

/// One colour of a red-black split: pixel (x, y) with `(x + y) % 2 == colour` lives at
/// `(y + 1) * stride + x / 2 + 1`; the zero border row/column lets the sweeps read
/// neighbours without branches (their weights are zero).
struct RbLayout {
    w: usize,
    h: usize,
    stride: usize,
}

impl RbLayout {
    fn new(w: usize, h: usize) -> Self {
        Self {
            w,
            h,
            stride: w.div_ceil(2) + 2,
        }
    }
    fn len(&self) -> usize {
        (self.h + 2) * self.stride
    }
    /// First x of `colour` in row y, and the number of such pixels.
    fn row(&self, colour: usize, y: usize) -> (usize, usize) {
        let s = (colour + y) % 2;
        (s, (self.w.saturating_sub(s)).div_ceil(2))
    }
}

/// Per-colour coefficients of the linear system of one fixed-point iteration.
struct RbSystem {
    /// Smoothness weight of the edges to the right and lower neighbours (the left and upper
    /// edges use the neighbours' own weights, stored in the other colour).
    ws: Vec<f32>,
    /// Right-hand sides (data term plus smoothness of the base flow).
    ru: Vec<f32>,
    rv: Vec<f32>,
    a12: Vec<f32>,
    /// Reciprocals of the diagonal (data + smoothness).
    inv11: Vec<f32>,
    inv22: Vec<f32>,
}

impl RbSystem {
    fn new(n: usize) -> Self {
        let z = || vec![0.0f32; n];
        Self {
            ws: z(),
            ru: z(),
            rv: z(),
            a12: z(),
            inv11: z(),
            inv22: z(),
        }
    }
}

/// Refines the flow `(u, v)` from `i0` to `i1` in place. The per-row loops run compiled
/// for AVX2 when the CPU has it (`plane::simd`): element-wise `f32` arithmetic without fused
/// multiply-add and reductions kept in order, so the same bits as the baseline build (test
/// `avx2_refinement_equals_baseline`).
pub fn refine(i0: &Plane, i1: &Plane, u: &mut Plane, v: &mut Plane, p: &VariationalParams) {
    refine_body(dynapix_simd::Avx2::detect(), i0, i1, u, v, p);
}

#[inline(always)]
fn refine_body(
    isa: Option<dynapix_simd::Avx2>,
    i0: &Plane,
    i1: &Plane,
    u: &mut Plane,
    v: &mut Plane,
    p: &VariationalParams,
) {
    if p.fixed_point_iterations == 0 || i0.w == 0 || i0.h == 0 {
        return;
    }
    let (w, h) = (i0.w, i0.h);
    let warped = warp_plane(i1, u, v);
    let dc = data_coeffs(i0, warped, p.zeta);
    let lay = RbLayout::new(w, h);
    let mut du = [vec![0.0f32; lay.len()], vec![0.0f32; lay.len()]];
    let mut dv = [vec![0.0f32; lay.len()], vec![0.0f32; lay.len()]];
    let mut sys = [RbSystem::new(lay.len()), RbSystem::new(lay.len())];
    let mut cu = Plane::zeros(w, h);
    let mut cv = Plane::zeros(w, h);
    let mut du_full = Plane::zeros(w, h);
    let mut dv_full = Plane::zeros(w, h);
    let mut ws = Plane::zeros(w, h);
    for _ in 0..p.fixed_point_iterations {
        merge_rb(&lay, &du, &mut du_full);
        merge_rb(&lay, &dv, &mut dv_full);
        smoothness_weights(isa, u, v, &du_full, &dv_full, p, &mut cu, &mut cv, &mut ws);
        let env = BuildEnv {
            lay: &lay,
            dc: &dc,
            u,
            v,
            du: &du_full,
            dv: &dv_full,
            ws: &ws,
            p,
        };
        env.fill_all(isa, &mut sys);
        for _ in 0..p.sor_iterations {
            for colour in 0..2 {
                sor_half_sweep(isa, &lay, colour, &sys, p.omega, &mut du, &mut dv);
            }
        }
    }
    merge_rb(&lay, &du, &mut du_full);
    merge_rb(&lay, &dv, &mut dv_full);
    u.data
        .par_iter_mut()
        .zip(du_full.data.par_iter())
        .with_min_len(MIN_PAR_PIXELS)
        .for_each(|(a, b)| *a += b);
    v.data
        .par_iter_mut()
        .zip(dv_full.data.par_iter())
        .with_min_len(MIN_PAR_PIXELS)
        .for_each(|(a, b)| *a += b);
}

/// Copies a red-black pair of buffers into a full row-major plane.
#[inline(always)]
fn merge_rb(lay: &RbLayout, src: &[Vec<f32>; 2], dst: &mut Plane) {
    let w = dst.w;
    let st = lay.stride;
    dst.data
        .par_chunks_mut(w)
        .enumerate()
        .with_min_len(min_rows(w))
        .for_each(|(y, row)| {
            let o = (y + 1) * st + 1;
            let (even, odd) = if y % 2 == 0 {
                (&src[0][o..o + st - 1], &src[1][o..o + st - 1])
            } else {
                (&src[1][o..o + st - 1], &src[0][o..o + st - 1])
            };
            // Pairs (even x, odd x), then the odd width's last pixel (an even x).
            let mut pairs = row.chunks_exact_mut(2);
            for ((pair, &e), &o) in (&mut pairs).zip(even).zip(odd) {
                pair[0] = e;
                pair[1] = o;
            }
            if let [last] = pairs.into_remainder() {
                *last = even[w / 2];
            }
        });
}

/// Robust smoothness weight per pixel from the forward differences of `w + dw`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn smoothness_weights(
    isa: Option<dynapix_simd::Avx2>,
    u: &Plane,
    v: &Plane,
    du: &Plane,
    dv: &Plane,
    p: &VariationalParams,
    cu: &mut Plane,
    cv: &mut Plane,
    ws: &mut Plane,
) {
    let (w, h) = (u.w, u.h);
    cu.data
        .par_iter_mut()
        .zip(u.data.par_iter().zip(du.data.par_iter()))
        .with_min_len(MIN_PAR_PIXELS)
        .for_each(|(c, (a, b))| *c = a + b);
    cv.data
        .par_iter_mut()
        .zip(v.data.par_iter().zip(dv.data.par_iter()))
        .with_min_len(MIN_PAR_PIXELS)
        .for_each(|(c, (a, b))| *c = a + b);
    let alpha2 = 0.5 * p.alpha;
    let eps2 = p.epsilon * p.epsilon;
    let (cu, cv) = (&*cu, &*cv);
    ws.data
        .par_chunks_mut(w)
        .enumerate()
        .with_min_len(min_rows(w))
        .for_each(|(y, row)| {
            simd(
                isa,
                #[inline(always)]
                || {
                    let o = y * w;
                    let yn = if y + 1 < h { o + w } else { o };
                    let (u0, v0) = (&cu.data[o..o + w], &cv.data[o..o + w]);
                    let (u1, v1) = (&cu.data[yn..yn + w], &cv.data[yn..yn + w]);
                    for x in 0..w {
                        let xn = if x + 1 < w { x + 1 } else { x };
                        let ux = u0[xn] - u0[x];
                        let vx = v0[xn] - v0[x];
                        let uy = u1[x] - u0[x];
                        let vy = v1[x] - v0[x];
                        row[x] = alpha2 / (ux * ux + uy * uy + vx * vx + vy * vy + eps2).sqrt();
                    }
                },
            )
        });
}

/// Everything needed to fill the per-colour systems of one fixed-point iteration.
struct BuildEnv<'a> {
    lay: &'a RbLayout,
    dc: &'a DataCoeffs,
    u: &'a Plane,
    v: &'a Plane,
    du: &'a Plane,
    dv: &'a Plane,
    ws: &'a Plane,
    p: &'a VariationalParams,
}

/// The system of one pixel from its smoothness edge weights `w` (left, right, up, down),
/// the base flow `u` and `v` (left, centre, right, up, down) and its data blocks `d`
/// (`a11`, `a22`, `b1`, `b2`): (`ru`, `rv`, `inv11`, `inv22`), the right-hand sides with the
/// base flow's differences to the neighbours and the reciprocal diagonals.
#[inline(always)]
fn pixel_system(w: [f32; 4], u: [f32; 5], v: [f32; 5], d: [f32; 4]) -> (f32, f32, f32, f32) {
    let [wl, wr, wu, wd] = w;
    let su = wl * (u[0] - u[1]) + wr * (u[2] - u[1]) + wu * (u[3] - u[1]) + wd * (u[4] - u[1]);
    let sv = wl * (v[0] - v[1]) + wr * (v[2] - v[1]) + wu * (v[3] - v[1]) + wd * (v[4] - v[1]);
    let sum = wl + wr + wu + wd;
    let [a11, a22, b1, b2] = d;
    (b1 + su, b2 + sv, 1.0 / (a11 + sum), 1.0 / (a22 + sum))
}

/// Row y of the flow, the smoothness weights and the data blocks, with the rows above and
/// below it (the row itself at the image border, where the weights are zero).
struct RowView<'a> {
    u: &'a [f32],
    v: &'a [f32],
    ws: &'a [f32],
    u_up: &'a [f32],
    v_up: &'a [f32],
    ws_up: &'a [f32],
    u_dn: &'a [f32],
    v_dn: &'a [f32],
    a11: &'a [f32],
    a22: &'a [f32],
    b1: &'a [f32],
    b2: &'a [f32],
    /// There is a row above (y > 0).
    has_up: bool,
    /// There is a row below (y + 1 < h).
    has_down: bool,
}

impl RowView<'_> {
    /// The system of pixel x ([`pixel_system`]): smoothness edge weights (zero across the
    /// image border) and the base flow's differences to the neighbours added to the
    /// right-hand sides. Returns (`ru`, `rv`, `inv11`, `inv22`).
    #[inline(always)]
    fn system_px(&self, x: usize) -> (f32, f32, f32, f32) {
        let w = self.u.len();
        let xl = x.saturating_sub(1);
        let xr = if x + 1 < w { x + 1 } else { x };
        let wl = if x > 0 { self.ws[xl] } else { 0.0 };
        let wr = if x + 1 < w { self.ws[x] } else { 0.0 };
        let wu = if self.has_up { self.ws_up[x] } else { 0.0 };
        let wd = if self.has_down { self.ws[x] } else { 0.0 };
        let (u, v) = (self.u, self.v);
        pixel_system(
            [wl, wr, wu, wd],
            [u[xl], u[x], u[xr], self.u_up[x], self.u_dn[x]],
            [v[xl], v[x], v[xr], self.v_up[x], self.v_dn[x]],
            [self.a11[x], self.a22[x], self.b1[x], self.b2[x]],
        )
    }
}

/// Mutable views of one padded row of every coefficient array of an [`RbSystem`].
struct RowMut<'a> {
    ws: &'a mut [f32],
    ru: &'a mut [f32],
    rv: &'a mut [f32],
    a12: &'a mut [f32],
    inv11: &'a mut [f32],
    inv22: &'a mut [f32],
}

/// Splits the interior rows of a system into per-row views (for row-parallel filling).
#[inline(always)]
fn rows_mut(s: &mut RbSystem, st: usize, h: usize) -> Vec<RowMut<'_>> {
    let r = st..(h + 1) * st;
    s.ws[r.clone()]
        .chunks_mut(st)
        .zip(s.ru[r.clone()].chunks_mut(st))
        .zip(s.rv[r.clone()].chunks_mut(st))
        .zip(s.a12[r.clone()].chunks_mut(st))
        .zip(s.inv11[r.clone()].chunks_mut(st))
        .zip(s.inv22[r].chunks_mut(st))
        .map(|(((((ws, ru), rv), a12), inv11), inv22)| RowMut {
            ws,
            ru,
            rv,
            a12,
            inv11,
            inv22,
        })
        .collect()
}

impl BuildEnv<'_> {
    /// Fills both colours' systems, rows in parallel.
    #[inline(always)]
    fn fill_all(&self, isa: Option<dynapix_simd::Avx2>, sys: &mut [RbSystem; 2]) {
        let (st, h, w) = (self.lay.stride, self.lay.h, self.lay.w);
        let [s0, s1] = sys;
        let mut jobs: Vec<(RowMut<'_>, RowMut<'_>)> = rows_mut(s0, st, h)
            .into_iter()
            .zip(rows_mut(s1, st, h))
            .collect();
        jobs.par_iter_mut()
            .enumerate()
            .with_min_len(min_rows(self.lay.w))
            .for_each_init(
                || vec![0.0f32; 10 * w],
                |scratch, (y, (r0, r1))| {
                    // A one-call closure, so it is inlined into the AVX2 build with the
                    // row's work.
                    simd(
                        isa,
                        #[inline(always)]
                        || self.fill_row_pair(y, scratch, r0, r1),
                    )
                },
            );
    }

    /// Fills row y of both colours' systems; `scratch` holds 10 × w values.
    #[inline(always)]
    fn fill_row_pair(
        &self,
        y: usize,
        scratch: &mut [f32],
        r0: &mut RowMut<'_>,
        r1: &mut RowMut<'_>,
    ) {
        let w = self.lay.w;
        // Data blocks, the row-order system, and a row of zeros.
        let (data, rest) = scratch.split_at_mut(5 * w);
        let (full, zeros) = rest.split_at_mut(4 * w);
        self.data_row(y, data);
        self.system_row(y, data, zeros, full);
        self.split_row(0, y, r0, data, full);
        self.split_row(1, y, r1, data, full);
    }

    /// Data-term blocks (a11, a12, a22, b1, b2) of row y, contiguous so the robust weights
    /// (square roots, divisions) vectorise.
    #[inline(always)]
    fn data_row(&self, y: usize, out: &mut [f32]) {
        let w = self.lay.w;
        let z2 = self.p.zeta * self.p.zeta;
        let eps2 = self.p.epsilon * self.p.epsilon;
        let (delta2, gamma2) = (0.5 * self.p.delta, 0.5 * self.p.gamma);
        let d = self.dc;
        let o = y * w;
        fn sub(a: &[f32], o: usize, w: usize) -> &[f32] {
            &a[o..o + w]
        }
        let row = |a| sub(a, o, w);
        let (bx, by, bz) = (row(&d.bx), row(&d.by), row(&d.bz));
        let (gxx, gxy, gxz) = (row(&d.gxx), row(&d.gxy), row(&d.gxz));
        let (gyx, gyy, gyz) = (row(&d.gyx), row(&d.gyy), row(&d.gyz));
        let (du, dv) = (row(&self.du.data), row(&self.dv.data));
        let (a11, rest) = out.split_at_mut(w);
        let (a12, rest) = rest.split_at_mut(w);
        let (a22, rest) = rest.split_at_mut(w);
        let (b1, b2) = rest.split_at_mut(w);
        let b2 = &mut b2[..w];
        for x in 0..w {
            let (ddu, ddv) = (du[x], dv[x]);
            // Brightness constancy (normalised), robust weight from the current increment.
            let r = bz[x] + bx[x] * ddu + by[x] * ddv;
            let wi = delta2 / (r * r + eps2).sqrt();
            // Gradient constancy.
            let rx = gxz[x] + gxx[x] * ddu + gxy[x] * ddv;
            let ry = gyz[x] + gyx[x] * ddu + gyy[x] * ddv;
            let wg = gamma2 / (rx * rx + ry * ry + eps2).sqrt();
            a11[x] = wi * bx[x] * bx[x] + wg * (gxx[x] * gxx[x] + gyx[x] * gyx[x]) + z2;
            a12[x] = wi * bx[x] * by[x] + wg * (gxx[x] * gxy[x] + gyx[x] * gyy[x]);
            a22[x] = wi * by[x] * by[x] + wg * (gxy[x] * gxy[x] + gyy[x] * gyy[x]) + z2;
            b1[x] = -wi * bz[x] * bx[x] - wg * (gxx[x] * gxz[x] + gyx[x] * gyz[x]);
            b2[x] = -wi * bz[x] * by[x] - wg * (gxy[x] * gxz[x] + gyy[x] * gyz[x]);
        }
    }

    /// The system of every pixel of row y, both colours, in row order: right-hand sides
    /// (`ru`, `rv`) and reciprocal diagonals (`inv11`, `inv22`) into `full` (4 × w), from the
    /// data blocks `data` of [`BuildEnv::data_row`] (`zeros`: w zeros). The interior pixels run without
    /// branches on contiguous slices (vectorised); the two border pixels take
    /// [`RowView::system_px`]. Both are the expressions of [`pixel_system`] in the
    /// same order, so the same bits (test `rows_of_the_system_equal_the_pixel_by_pixel_system`).
    #[inline(always)]
    fn system_row(&self, y: usize, data: &[f32], zeros: &[f32], full: &mut [f32]) {
        let r = self.row_view(y, data);
        let w = self.lay.w;
        let (ru, rest) = full.split_at_mut(w);
        let (rv, rest) = rest.split_at_mut(w);
        let (inv11, rest) = rest.split_at_mut(w);
        let inv22 = &mut rest[..w];
        for x in [0, w - 1] {
            (ru[x], rv[x], inv11[x], inv22[x]) = r.system_px(x);
        }
        if w < 3 {
            return;
        }
        let (u, v, ws) = (r.u, r.v, r.ws);
        let (u_up, v_up, u_dn, v_dn) = (r.u_up, r.v_up, r.u_dn, r.v_dn);
        let (a11, a22, b1, b2) = (r.a11, r.a22, r.b1, r.b2);
        // Vertical edge weights of the row: zero across the image border.
        let zeros = &zeros[..w];
        let wu_row = if r.has_up { r.ws_up } else { zeros };
        let wd_row = if r.has_down { ws } else { zeros };
        // Interior pixels 1..w-1: x - 1 at index i, x at i + 1, x + 1 at i + 2.
        let n = w - 2;
        let (ul, uc, ur) = (&u[..n], &u[1..n + 1], &u[2..n + 2]);
        let (vl, vc, vr) = (&v[..n], &v[1..n + 1], &v[2..n + 2]);
        let (uu, ud) = (&u_up[1..n + 1], &u_dn[1..n + 1]);
        let (vu, vd) = (&v_up[1..n + 1], &v_dn[1..n + 1]);
        let (wl, wr) = (&ws[..n], &ws[1..n + 1]);
        let (wu, wd) = (&wu_row[1..n + 1], &wd_row[1..n + 1]);
        let (a11, a22, b1, b2) = (&a11[1..n + 1], &a22[1..n + 1], &b1[1..n + 1], &b2[1..n + 1]);
        let ru = &mut ru[1..n + 1];
        let rv = &mut rv[1..n + 1];
        let inv11 = &mut inv11[1..n + 1];
        let inv22 = &mut inv22[1..n + 1];
        for i in 0..n {
            (ru[i], rv[i], inv11[i], inv22[i]) = pixel_system(
                [wl[i], wr[i], wu[i], wd[i]],
                [ul[i], uc[i], ur[i], uu[i], ud[i]],
                [vl[i], vc[i], vr[i], vu[i], vd[i]],
                [a11[i], a22[i], b1[i], b2[i]],
            );
        }
    }

    /// The slices of row y (and of the rows above and below it) that its system reads, with
    /// the data blocks `data` of [`BuildEnv::data_row`].
    #[inline(always)]
    fn row_view<'b>(&'b self, y: usize, data: &'b [f32]) -> RowView<'b> {
        let (w, h) = (self.lay.w, self.lay.h);
        let o = y * w;
        // Neighbour rows (the row itself at the border, where the weight is zero anyway).
        let up = if y > 0 { o - w } else { o };
        let dn = if y + 1 < h { o + w } else { o };
        let row = |p: &'b Plane, o: usize| &p.data[o..o + w];
        RowView {
            u: row(self.u, o),
            v: row(self.v, o),
            ws: row(self.ws, o),
            u_up: row(self.u, up),
            v_up: row(self.v, up),
            ws_up: row(self.ws, up),
            u_dn: row(self.u, dn),
            v_dn: row(self.v, dn),
            a11: &data[..w],
            a22: &data[2 * w..3 * w],
            b1: &data[3 * w..4 * w],
            b2: &data[4 * w..5 * w],
            has_up: y > 0,
            has_down: y + 1 < h,
        }
    }

    /// Copies one colour's pixels of row y from the row-order system `full`
    /// ([`BuildEnv::system_row`]) and the data blocks `data` into that colour's padded row.
    #[inline(always)]
    fn split_row(&self, colour: usize, y: usize, s: &mut RowMut<'_>, data: &[f32], full: &[f32]) {
        let w = self.lay.w;
        let o = y * w;
        let ws = &self.ws.data[o..o + w];
        let (ru, rv) = (&full[..w], &full[w..2 * w]);
        let (inv11, inv22) = (&full[2 * w..3 * w], &full[3 * w..4 * w]);
        let (x0, len) = self.lay.row(colour, y);
        let pick = |dst: &mut [f32], src: &[f32]| {
            // Raw weight even at the border: the sweeps multiply it by the zero padding.
            for (d, &v) in dst[1..1 + len].iter_mut().zip(src[x0..].iter().step_by(2)) {
                *d = v;
            }
        };
        pick(s.ws, ws);
        pick(s.ru, ru);
        pick(s.rv, rv);
        pick(s.a12, &data[w..2 * w]);
        pick(s.inv11, inv11);
        pick(s.inv22, inv22);
    }

    /// One colour's row of the system a pixel at a time ([`RowView::system_px`]): the test
    /// reference of [`BuildEnv::system_row`] and [`BuildEnv::split_row`].
    #[cfg(test)]
    fn fill_row_reference(&self, colour: usize, y: usize, s: &mut RowMut<'_>, data: &[f32]) {
        let w = self.lay.w;
        let (x0, len) = self.lay.row(colour, y);
        let row = self.row_view(y, data);
        for k in 0..len {
            let (x, j) = (x0 + 2 * k, k + 1);
            let (ru, rv, inv11, inv22) = row.system_px(x);
            s.ws[j] = self.ws.data[y * w + x];
            s.ru[j] = ru;
            s.rv[j] = rv;
            s.a12[j] = data[w + x];
            s.inv11[j] = inv11;
            s.inv22[j] = inv22;
        }
    }
}

/// Updates all pixels of one colour; they only read the other colour, so rows run in
/// parallel, and the zero padding makes the inner loop branch-free (a missing neighbour
/// contributes weight × 0).
#[inline(always)]
fn sor_half_sweep(
    isa: Option<dynapix_simd::Avx2>,
    lay: &RbLayout,
    colour: usize,
    sys: &[RbSystem; 2],
    omega: f32,
    du: &mut [Vec<f32>; 2],
    dv: &mut [Vec<f32>; 2],
) {
    let (h, st) = (lay.h, lay.stride);
    let [du0, du1] = du;
    let [dv0, dv1] = dv;
    let (du_c, du_o, dv_c, dv_o) = if colour == 0 {
        (du0, &*du1, dv0, &*dv1)
    } else {
        (du1, &*du0, dv1, &*dv0)
    };
    let s = &sys[colour];
    let ws_o = &sys[1 - colour].ws;
    du_c[st..(h + 1) * st]
        .par_chunks_mut(st)
        .zip(dv_c[st..(h + 1) * st].par_chunks_mut(st))
        .enumerate()
        .with_min_len(min_rows(st))
        .for_each(|(y, (ru_row, rv_row))| {
            simd(
                isa,
                #[inline(always)]
                || {
                    let (sft, len) = lay.row(colour, y);
                    let o = (y + 1) * st;
                    // Other colour, padded indices: left neighbour of k at k + sft, right at
                    // k + sft + 1; upper/lower neighbours at k + 1 in rows y - 1 and y + 1.
                    let ou = &du_o[o..o + st];
                    let ov = &dv_o[o..o + st];
                    let (ou_up, ov_up) = (&du_o[o - st..o], &dv_o[o - st..o]);
                    let (ou_dn, ov_dn) = (&du_o[o + st..o + 2 * st], &dv_o[o + st..o + 2 * st]);
                    let c = o + 1;
                    let w_own = &s.ws[c..c + len];
                    let w_left = &ws_o[o + sft..o + sft + len];
                    let w_up = &ws_o[o - st + 1..o - st + 1 + len];
                    let (bu, bv, a12) = (&s.ru[c..c + len], &s.rv[c..c + len], &s.a12[c..c + len]);
                    let (i11, i22) = (&s.inv11[c..c + len], &s.inv22[c..c + len]);
                    let (ul, ur) = (&ou[sft..sft + len], &ou[sft + 1..sft + 1 + len]);
                    let (vl, vr) = (&ov[sft..sft + len], &ov[sft + 1..sft + 1 + len]);
                    let (uu, ud) = (&ou_up[1..1 + len], &ou_dn[1..1 + len]);
                    let (vu, vd) = (&ov_up[1..1 + len], &ov_dn[1..1 + len]);
                    let cur_u = &mut ru_row[1..1 + len];
                    let cur_v = &mut rv_row[1..1 + len];
                    for k in 0..len {
                        let nu = w_own[k] * (ur[k] + ud[k]) + w_left[k] * ul[k] + w_up[k] * uu[k];
                        let nv = w_own[k] * (vr[k] + vd[k]) + w_left[k] * vl[k] + w_up[k] * vu[k];
                        let (cu, cv) = (cur_u[k], cur_v[k]);
                        let new_u = (bu[k] + nu - a12[k] * cv) * i11[k];
                        let u1 = cu + omega * (new_u - cu);
                        let new_v = (bv[k] + nv - a12[k] * u1) * i22[k];
                        cur_u[k] = u1;
                        cur_v[k] = cv + omega * (new_v - cv);
                    }
                },
            )
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn texture(w: usize, h: usize, sx: f32, sy: f32) -> Plane {
        let mut p = Plane::zeros(w, h);
        for y in 0..h {
            for x in 0..w {
                let (xf, yf) = (x as f32 + sx, y as f32 + sy);
                p.data[y * w + x] = 128.0
                    + 50.0 * (xf * 0.31).sin() * (yf * 0.23).cos()
                    + 30.0 * ((xf + yf) * 0.17).sin();
            }
        }
        p
    }

    #[test]
    fn merging_the_colours_puts_every_pixel_where_the_layout_says() {
        for (w, h) in [(1, 1), (2, 3), (7, 4), (8, 5), (161, 3)] {
            let lay = RbLayout::new(w, h);
            let src = [
                (0..lay.len()).map(|i| i as f32).collect::<Vec<_>>(),
                (0..lay.len())
                    .map(|i| -(i as f32) - 1.0)
                    .collect::<Vec<_>>(),
            ];
            let mut dst = Plane::zeros(w, h);
            merge_rb(&lay, &src, &mut dst);
            for y in 0..h {
                for x in 0..w {
                    let want = src[(x + y) % 2][(y + 1) * lay.stride + x / 2 + 1];
                    assert_eq!(dst.data[y * w + x], want, "({x}, {y}) of {w}×{h}");
                }
            }
        }
    }

    #[test]
    fn refinement_reduces_error_of_a_noisy_flow() {
        let (w, h) = (48, 40);
        let i0 = texture(w, h, 0.0, 0.0);
        // i1(x + t) = i0(x) with t = (0.6, -0.4).
        let i1 = texture(w, h, -0.6, 0.4);
        let mut u = Plane::zeros(w, h);
        let mut v = Plane::zeros(w, h);
        // Truth plus deterministic high-frequency noise of ±0.3 px.
        for y in 0..h {
            for x in 0..w {
                let n = 0.3 * ((x * 7 + y * 13) as f32 * 1.7).sin();
                u.data[y * w + x] = 0.6 + n;
                v.data[y * w + x] = -0.4 - n;
            }
        }
        let epe = |u: &Plane, v: &Plane| {
            let (mut err, mut cnt) = (0.0, 0.0);
            for y in 4..h - 4 {
                for x in 4..w - 4 {
                    let i = y * w + x;
                    err += ((u.data[i] - 0.6).powi(2) + (v.data[i] + 0.4).powi(2)).sqrt();
                    cnt += 1.0;
                }
            }
            err / cnt
        };
        let before = epe(&u, &v);
        refine(&i0, &i1, &mut u, &mut v, &VariationalParams::default());
        let after = epe(&u, &v);
        assert!(after < 0.5 * before, "epe before {before}, after {after}");
        assert!(u.data.iter().chain(&v.data).all(|a| a.is_finite()));
    }

    #[test]
    fn avx2_refinement_equals_baseline() {
        let (w, h) = (97, 66);
        let i0 = texture(w, h, 0.0, 0.0);
        let i1 = texture(w, h, -1.3, 0.7);
        let start = |k: f32| {
            let mut u = Plane::zeros(w, h);
            for (i, x) in u.data.iter_mut().enumerate() {
                *x = k + 0.4 * ((i * 7) as f32 * 0.37).sin();
            }
            u
        };
        let (mut u1, mut v1) = (start(1.2), start(-0.6));
        let (mut u2, mut v2) = (u1.clone(), v1.clone());
        let p = VariationalParams::default();
        refine(&i0, &i1, &mut u1, &mut v1, &p);
        refine_body(None, &i0, &i1, &mut u2, &mut v2, &p);
        let bits = |a: &Plane| a.data.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&u1), bits(&u2));
        assert_eq!(bits(&v1), bits(&v2));
    }

    #[test]
    fn rows_of_the_system_equal_the_pixel_by_pixel_system() {
        let p = VariationalParams::default();
        for (w, h) in [(1, 1), (2, 3), (3, 2), (7, 4), (8, 5), (33, 6)] {
            let i0 = texture(w, h, 0.0, 0.0);
            let i1 = texture(w, h, -1.3, 0.7);
            let wave = |k: f32, s: f32| {
                let mut a = Plane::zeros(w, h);
                for (i, x) in a.data.iter_mut().enumerate() {
                    *x = k + s * ((i * 7) as f32 * 0.37).sin();
                }
                a
            };
            let (u, v) = (wave(1.2, 0.4), wave(-0.6, 0.4));
            let (du, dv) = (wave(0.1, 0.2), wave(-0.2, 0.3));
            let dc = data_coeffs(&i0, warp_plane(&i1, &u, &v), p.zeta);
            let (mut cu, mut cv, mut ws) =
                (Plane::zeros(w, h), Plane::zeros(w, h), Plane::zeros(w, h));
            smoothness_weights(None, &u, &v, &du, &dv, &p, &mut cu, &mut cv, &mut ws);
            let lay = RbLayout::new(w, h);
            let env = BuildEnv {
                lay: &lay,
                dc: &dc,
                u: &u,
                v: &v,
                du: &du,
                dv: &dv,
                ws: &ws,
                p: &p,
            };
            let mut fast = [RbSystem::new(lay.len()), RbSystem::new(lay.len())];
            env.fill_all(dynapix_simd::Avx2::detect(), &mut fast);
            let mut slow = [RbSystem::new(lay.len()), RbSystem::new(lay.len())];
            let mut data = vec![0.0f32; 5 * w];
            let [s0, s1] = &mut slow;
            for (y, (mut r0, mut r1)) in rows_mut(s0, lay.stride, h)
                .into_iter()
                .zip(rows_mut(s1, lay.stride, h))
                .enumerate()
            {
                env.data_row(y, &mut data);
                env.fill_row_reference(0, y, &mut r0, &data);
                env.fill_row_reference(1, y, &mut r1, &data);
            }
            let bits = |a: &[f32]| a.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            for (f, s) in fast.iter().zip(&slow) {
                for (a, b) in [
                    (&f.ws, &s.ws),
                    (&f.ru, &s.ru),
                    (&f.rv, &s.rv),
                    (&f.a12, &s.a12),
                    (&f.inv11, &s.inv11),
                    (&f.inv22, &s.inv22),
                ] {
                    assert_eq!(bits(a), bits(b), "{w}×{h}");
                }
            }
        }
    }

    #[test]
    fn uniform_images_stay_finite_and_zero() {
        let i0 = Plane {
            w: 7,
            h: 5,
            data: vec![42.0; 35],
        };
        let mut u = Plane::zeros(7, 5);
        let mut v = Plane::zeros(7, 5);
        refine(&i0, &i0, &mut u, &mut v, &VariationalParams::default());
        assert!(u.data.iter().chain(&v.data).all(|a| *a == 0.0));
    }
}
