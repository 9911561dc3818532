//! Splatting-based view synthesis (paper §3.1 "Splatting-based View Synthesis", Eq. 4-5;
//! reference `Warper.forward_warp`, spec §1.5): every source pixel is lifted to 3-D with its
//! depth, moved into the target camera and splatted bilinearly onto the four surrounding
//! target pixels, with a depth-dependent weight so the nearest surface wins.
//!
//! - `Mode::Reference` replicates the reference: invalid depth is projected too, the one-pixel
//!   padding frame catches points outside the image, corners come from floor/ceil (an integer
//!   coordinate hits one pixel four times) and the weight is divided by
//!   `exp(50·ln(1+z)/max ln(1+z))`, accumulated in `f64`.
//! - `Mode::Paper` fixes the defects of spec §7.7: z ≤ 0 and points behind the target camera
//!   are skipped, a first pass builds a z-buffer of the nearest depth per target pixel and the
//!   second pass weights contributions by `exp(−(z − z_min)/(τ·z_min))` (a soft z-buffer with a
//!   fixed relative temperature τ), and pixels that receive too little weight are holes.
//!
//! The depth in the target view is splatted with the same weights, so a neighbour's depth can
//! be carried into the current view (background reconstruction needs it).
//!
//! Lens distortion: images are raw (distorted, as the sensor gives them). With a distorted
//! camera a source pixel is back-projected along its undistorted ray and the moved point is
//! projected through the distortion to its raw target pixel. The rays come from a
//! [`PixelRays`] table built once per camera and kept for the process ([`pixel_rays`]), so
//! the per-pixel loop only looks them up. An undistorted camera takes the plain pinhole path,
//! bit for bit what it always computed.

use std::sync::{Arc, Mutex};

use dynapix_geometry::{PinholeCamera, PixelRays, Se3};
use image::{Rgb, RgbImage};
use serde::{Deserialize, Serialize};

use crate::{FloatImage, Mode, MotionError, check_size};

/// Parameters of the splatting. `Default` = paper mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SplatParams {
    /// Reference or paper behaviour.
    pub mode: Mode,
    /// Reference: depths are clamped to `[0, depth_clamp]` before the log weight.
    pub depth_clamp: f64,
    /// Reference: exponent scale of the near-surface weight (`exp(sharpness·ℓ/max ℓ)`).
    pub sharpness: f64,
    /// Paper: relative depth temperature τ of the soft z-buffer.
    pub z_temperature: f32,
    /// Paper: contributions more than this many temperatures behind the nearest surface are
    /// dropped (their weight would be below `exp(−cutoff)`).
    pub z_cutoff: f32,
    /// Paper: a target pixel whose accumulated bilinear weight is below this is a hole.
    pub min_weight: f32,
    /// Paper: projected depths at or below this (metres) are behind the camera and skipped.
    pub min_depth: f32,
}

impl Default for SplatParams {
    fn default() -> Self {
        Self::new(Mode::Paper)
    }
}

impl SplatParams {
    /// Defaults of `mode`.
    pub fn new(mode: Mode) -> Self {
        Self {
            mode,
            depth_clamp: 100.0,
            sharpness: 50.0,
            z_temperature: 0.02,
            z_cutoff: 8.0,
            min_weight: 0.1,
            min_depth: 1e-3,
        }
    }
}

/// A source image rendered into the target view.
#[derive(Clone, Debug)]
pub struct Warped {
    /// Colour in the target view (holes are black).
    pub image: RgbImage,
    /// Depth in the target view, metres (holes are 0).
    pub depth: FloatImage,
    /// Row-major, `true` where nothing (or too little) landed.
    pub holes: Vec<bool>,
}

/// A projected source point: target coordinates and depth in the target view.
struct Projected {
    u: f64,
    v: f64,
    z: f64,
}

/// How many cameras' ray tables [`pixel_rays`] keeps (a run uses one camera; tests a few).
const RAY_CACHE_SIZE: usize = 4;

/// Ray tables of the cameras seen so far, most recent last.
static RAY_CACHE: Mutex<Vec<Arc<PixelRays>>> = Mutex::new(Vec::new());

/// The per-pixel undistorted rays of `cam`, built on first use and shared afterwards (a
/// small process-wide cache keyed by the full camera); `None` for an undistorted camera,
/// which needs no table. The table is a pure function of the camera, so the cache cannot
/// change any result.
pub fn pixel_rays(cam: &PinholeCamera) -> Option<Arc<PixelRays>> {
    if !cam.is_distorted() {
        return None;
    }
    Some(cached_rays(cam))
}

/// The ray table of any camera, distorted or not, from the cache of [`pixel_rays`] (built on
/// first use). Callers that walk the table for every pixel (the rigidity cue) use this
/// instead of building a `PixelRays` per frame.
pub fn cached_rays(cam: &PinholeCamera) -> Arc<PixelRays> {
    // A panic elsewhere while the lock was held leaves a valid list behind: keep using it.
    let mut cache = RAY_CACHE.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(r) = cache.iter().find(|r| r.camera() == cam) {
        return Arc::clone(r);
    }
    // Built under the lock so that parallel splats of the same camera build it once.
    let rays = Arc::new(PixelRays::new(cam));
    if cache.len() >= RAY_CACHE_SIZE {
        cache.remove(0);
    }
    cache.push(Arc::clone(&rays));
    rays
}

fn project_all(
    src_depth: &FloatImage,
    t_ts: &Se3,
    cam: &PinholeCamera,
    skip_invalid: bool,
) -> Vec<Option<Projected>> {
    use rayon::prelude::*;
    if let Some(rays) = pixel_rays(cam) {
        return project_all_distorted(src_depth, t_ts, &rays, skip_invalid);
    }
    let (w, h) = src_depth.dimensions();
    let r = t_ts.rotation.to_rotation_matrix();
    let r = *r.matrix();
    let t = t_ts.translation.vector;
    let depth = src_depth.as_raw();
    let mut out: Vec<Option<Projected>> = Vec::with_capacity(w as usize * h as usize);
    // Rows are independent; each is written to its own slice, so the result does not depend
    // on the thread count.
    out.resize_with(w as usize * h as usize, || None);
    out.par_chunks_mut(w as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let ny = (y as f64 - cam.cy) / cam.fy;
            for (x, o) in row.iter_mut().enumerate() {
                let z = depth[y * w as usize + x] as f64;
                if skip_invalid && !(z > 0.0 && z.is_finite()) {
                    continue;
                }
                let nx = (x as f64 - cam.cx) / cam.fx;
                let p = nalgebra::Vector3::new(nx * z, ny * z, z);
                let q = r * p + t;
                let u = cam.fx * q.x / q.z + cam.cx;
                let v = cam.fy * q.y / q.z + cam.cy;
                if !(u.is_finite() && v.is_finite() && q.z.is_finite()) {
                    // The reference sends these to the clipped border, cropped away later.
                    continue;
                }
                *o = Some(Projected { u, v, z: q.z });
            }
        });
    out
}

/// [`project_all`] for a distorted camera: rays from the table, targets through the lens.
fn project_all_distorted(
    src_depth: &FloatImage,
    t_ts: &Se3,
    rays: &PixelRays,
    skip_invalid: bool,
) -> Vec<Option<Projected>> {
    use rayon::prelude::*;
    let (w, h) = src_depth.dimensions();
    let r = *t_ts.rotation.to_rotation_matrix().matrix();
    let t = t_ts.translation.vector;
    let depth = src_depth.as_raw();
    let mut out: Vec<Option<Projected>> = Vec::with_capacity(w as usize * h as usize);
    out.resize_with(w as usize * h as usize, || None);
    out.par_chunks_mut(w as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let ray_row = rays.row(y as u32);
            for ((x, o), ray) in row.iter_mut().enumerate().zip(ray_row) {
                let z = depth[y * w as usize + x] as f64;
                if skip_invalid && !(z > 0.0 && z.is_finite()) {
                    continue;
                }
                let q = r * nalgebra::Vector3::new(ray[0] * z, ray[1] * z, z) + t;
                // Behind the target camera the lens model means nothing; the reference's
                // projection of such points is only defined for the ideal pinhole.
                let Some(uv) = rays.project(&nalgebra::Point3::from(q)) else {
                    continue;
                };
                if !(uv.x.is_finite() && uv.y.is_finite() && q.z.is_finite()) {
                    continue;
                }
                *o = Some(Projected {
                    u: uv.x,
                    v: uv.y,
                    z: q.z,
                });
            }
        });
    out
}

/// Renders `src` (with its depth `src_depth`, metres) into the target view; `t_ts` maps
/// source-camera points into the target camera (`T_ts = T_wt⁻¹ · T_ws`). With a distorted
/// `cam`, both images are raw and the lens is modelled (see the module doc).
pub fn splat(
    src: &RgbImage,
    src_depth: &FloatImage,
    t_ts: &Se3,
    cam: &PinholeCamera,
    params: &SplatParams,
) -> Result<Warped, MotionError> {
    let size = (cam.width, cam.height);
    check_size("splat source image", size, src.dimensions())?;
    check_size("splat source depth", size, src_depth.dimensions())?;
    match params.mode {
        Mode::Reference => Ok(splat_reference(src, src_depth, t_ts, cam, params)),
        Mode::Paper => Ok(splat_paper(src, src_depth, t_ts, cam, params)),
    }
}

fn splat_reference(
    src: &RgbImage,
    src_depth: &FloatImage,
    t_ts: &Se3,
    cam: &PinholeCamera,
    params: &SplatParams,
) -> Warped {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let pts = project_all(src_depth, t_ts, cam, false);
    let logz = |z: f64| (z.clamp(0.0, params.depth_clamp)).ln_1p();
    let max_l = pts
        .iter()
        .flatten()
        .map(|p| logz(p.z))
        .fold(0.0f64, f64::max);
    // Padded accumulators: one extra pixel on each side catches out-of-image hits.
    let pw = w + 2;
    let mut acc = vec![[0.0f64; 5]; pw * (h + 2)]; // r, g, b, z, weight
    let xmax = (w + 1) as f64;
    let ymax = (h + 1) as f64;
    for (i, p) in pts.iter().enumerate() {
        let Some(p) = p else { continue };
        let dw = if max_l > 0.0 {
            (params.sharpness * logz(p.z) / max_l).exp()
        } else {
            1.0
        };
        let (px, py) = (p.u + 1.0, p.v + 1.0);
        let (x0, y0) = (px.floor().clamp(0.0, xmax), py.floor().clamp(0.0, ymax));
        let (x1, y1) = (px.ceil().clamp(0.0, xmax), py.ceil().clamp(0.0, ymax));
        let (px, py) = (px.clamp(0.0, xmax), py.clamp(0.0, ymax));
        let c = src.as_raw();
        let col = [
            c[3 * i] as f64,
            c[3 * i + 1] as f64,
            c[3 * i + 2] as f64,
            p.z,
        ];
        let corners = [
            ((1.0 - (py - y0)) * (1.0 - (px - x0)), y0, x0),
            ((1.0 - (y1 - py)) * (1.0 - (px - x0)), y1, x0),
            ((1.0 - (py - y0)) * (1.0 - (x1 - px)), y0, x1),
            ((1.0 - (y1 - py)) * (1.0 - (x1 - px)), y1, x1),
        ];
        for (wk, ty, tx) in corners {
            let wk = wk / dw;
            let a = &mut acc[ty as usize * pw + tx as usize];
            for k in 0..4 {
                a[k] += wk * col[k];
            }
            a[4] += wk;
        }
    }
    let mut image = RgbImage::new(cam.width, cam.height);
    let mut depth = FloatImage::new(cam.width, cam.height);
    let mut holes = vec![true; w * h];
    for y in 0..h {
        for x in 0..w {
            let a = &acc[(y + 1) * pw + x + 1];
            if a[4] > 0.0 {
                let px = |k: usize| (a[k] / a[4]).round().clamp(0.0, 255.0) as u8;
                image.put_pixel(x as u32, y as u32, Rgb([px(0), px(1), px(2)]));
                depth.put_pixel(x as u32, y as u32, image::Luma([(a[3] / a[4]) as f32]));
                holes[y * w + x] = false;
            }
        }
    }
    Warped {
        image,
        depth,
        holes,
    }
}

/// Bilinear corners `(weight, target index)` of a point inside the image, paper mode.
fn corners(u: f64, v: f64, w: usize, h: usize) -> [(f32, usize); 4] {
    let (x0, y0) = (u.floor(), v.floor());
    let (fx, fy) = ((u - x0) as f32, (v - y0) as f32);
    let mut out = [(0.0f32, 0usize); 4];
    let cand = [
        ((1.0 - fx) * (1.0 - fy), x0, y0),
        (fx * (1.0 - fy), x0 + 1.0, y0),
        ((1.0 - fx) * fy, x0, y0 + 1.0),
        (fx * fy, x0 + 1.0, y0 + 1.0),
    ];
    for (k, (wk, cx, cy)) in cand.into_iter().enumerate() {
        if wk > 0.0 && cx >= 0.0 && cy >= 0.0 && (cx as usize) < w && (cy as usize) < h {
            out[k] = (wk, cy as usize * w + cx as usize);
        }
    }
    out
}

/// `≈ exp(−b)` for b ≥ 0: the reciprocal of the cubic Taylor polynomial of `e^b`. Monotone,
/// 1 at 0, within 10 % of `exp(−b)` for b ≤ 1.5 and decaying like `b⁻³` beyond, which is
/// all a soft z-buffer needs; an `exp` per bilinear corner would dominate the splatting time.
#[inline]
fn soft_weight(b: f32) -> f32 {
    let b = b.max(0.0);
    1.0 / (1.0 + b * (1.0 + b * (0.5 + b / 6.0)))
}

fn splat_paper(
    src: &RgbImage,
    src_depth: &FloatImage,
    t_ts: &Se3,
    cam: &PinholeCamera,
    params: &SplatParams,
) -> Warped {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let pts = project_all(src_depth, t_ts, cam, true);
    let inside = |p: &Projected| {
        p.z > params.min_depth as f64
            && p.u > -1.0
            && p.v > -1.0
            && p.u < w as f64
            && p.v < h as f64
    };
    // Pass 1: nearest depth per target pixel. Corners with a tiny bilinear share do not claim
    // the pixel, so a surface edge does not occlude the pixel next to it.
    let claim = 0.05f32;
    let mut zmin = vec![f32::INFINITY; w * h];
    for p in pts.iter().flatten().filter(|p| inside(p)) {
        let z = p.z as f32;
        for (wk, t) in corners(p.u, p.v, w, h) {
            if wk > claim && z < zmin[t] {
                zmin[t] = z;
            }
        }
    }
    // Pass 2: soft z-buffer accumulation.
    let mut acc = vec![[0.0f32; 5]; w * h];
    let c = src.as_raw();
    for (i, p) in pts.iter().enumerate() {
        let Some(p) = p else { continue };
        if !inside(p) {
            continue;
        }
        let z = p.z as f32;
        let col = [c[3 * i] as f32, c[3 * i + 1] as f32, c[3 * i + 2] as f32, z];
        for (wk, t) in corners(p.u, p.v, w, h) {
            if wk <= 0.0 {
                continue;
            }
            let zm = zmin[t].min(z);
            let behind = (z - zm) / (params.z_temperature * zm);
            if behind > params.z_cutoff {
                continue;
            }
            let wt = wk * soft_weight(behind);
            let a = &mut acc[t];
            for k in 0..4 {
                a[k] += wt * col[k];
            }
            a[4] += wt;
        }
    }
    let mut image = RgbImage::new(cam.width, cam.height);
    let mut depth = FloatImage::new(cam.width, cam.height);
    let mut holes = vec![true; w * h];
    for (t, a) in acc.iter().enumerate() {
        if a[4] >= params.min_weight {
            let px = |k: usize| (a[k] / a[4]).round().clamp(0.0, 255.0) as u8;
            let (x, y) = ((t % w) as u32, (t / w) as u32);
            image.put_pixel(x, y, Rgb([px(0), px(1), px(2)]));
            depth.put_pixel(x, y, image::Luma([a[3] / a[4]]));
            holes[t] = false;
        }
    }
    Warped {
        image,
        depth,
        holes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{Scene, small_camera, small_distorted_camera};

    /// Mean absolute green difference between a warp and the truth over non-hole pixels, and
    /// the number of those pixels.
    fn warp_error(out: &Warped, truth: &RgbImage) -> (f64, usize) {
        let mut n = 0;
        let mut err = 0.0f64;
        for (i, (a, b)) in out.image.pixels().zip(truth.pixels()).enumerate() {
            if !out.holes[i] {
                n += 1;
                err += (a.0[1] as f64 - b.0[1] as f64).abs();
            }
        }
        (err / n.max(1) as f64, n)
    }

    #[test]
    fn distortion_is_modelled_and_ray_tables_are_shared() {
        let cam = small_distorted_camera();
        let mut ideal = cam.clone();
        ideal.dist = [0.0; 5];
        let scene = Scene::default();
        // Identity: every raw pixel goes back to itself through the lens.
        let (img, depth) = scene.render(&cam, &Se3::identity(), false, 0.0);
        let same = splat(
            &img,
            &depth,
            &Se3::identity(),
            &cam,
            &SplatParams::default(),
        )
        .unwrap();
        assert_eq!(same.image, img);
        // A neighbour seen through the distorted lens (turned by 4.6° and moved by 15 cm)
        // lands on the current raw image; the ideal pinhole model misplaces it.
        let t_wn =
            dynapix_geometry::se3::exp(&nalgebra::Vector6::new(0.0, 0.08, 0.0, 0.15, 0.02, 0.0));
        let (cur, _) = scene.render(&cam, &Se3::identity(), false, 0.0);
        let (nb, nb_depth) = scene.render(&cam, &t_wn, false, 0.0);
        let (aware, n) = warp_error(
            &splat(&nb, &nb_depth, &t_wn, &cam, &SplatParams::default()).unwrap(),
            &cur,
        );
        let (ignoring, _) = warp_error(
            &splat(&nb, &nb_depth, &t_wn, &ideal, &SplatParams::default()).unwrap(),
            &cur,
        );
        assert!(n > 5000, "{n}");
        assert!(
            aware < 4.0 && aware < 0.7 * ignoring,
            "lens {aware}, pinhole {ignoring}"
        );
        // Both modes accept the distorted camera; the table is built once and shared.
        let r = splat(
            &nb,
            &nb_depth,
            &t_wn,
            &cam,
            &SplatParams::new(Mode::Reference),
        )
        .unwrap();
        assert!(warp_error(&r, &cur).0 < ignoring);
        let a = pixel_rays(&cam).expect("distorted");
        assert!(Arc::ptr_eq(&a, &pixel_rays(&cam).expect("cached")));
        assert!(pixel_rays(&ideal).is_none());
    }

    #[test]
    fn soft_weight_tracks_exp() {
        for i in 0..=15 {
            let b = i as f32 * 0.1;
            let (a, e) = (soft_weight(b), (-b).exp());
            assert!((a - e).abs() <= 0.1 * e, "{b}: {a} vs {e}");
        }
        assert_eq!(soft_weight(0.0), 1.0);
        assert!(soft_weight(8.0) < 0.01);
    }

    #[test]
    fn identity_pose_reproduces_the_image() {
        let cam = small_camera();
        let scene = Scene::default();
        let (img, depth) = scene.render(&cam, &Se3::identity(), false, 0.0);
        for mode in [Mode::Paper, Mode::Reference] {
            let out = splat(
                &img,
                &depth,
                &Se3::identity(),
                &cam,
                &SplatParams::new(mode),
            )
            .unwrap();
            assert_eq!(out.image, img, "{mode:?}");
            assert!(out.holes.iter().all(|&h| !h), "{mode:?}");
            for (a, b) in out.depth.pixels().zip(depth.pixels()) {
                assert!((a.0[0] - b.0[0]).abs() < 1e-4);
            }
        }
    }

    #[test]
    fn camera_motion_is_undone_away_from_holes() {
        let cam = small_camera();
        let scene = Scene::default();
        let t_wc = Se3::identity();
        let t_wn =
            dynapix_geometry::se3::exp(&nalgebra::Vector6::new(0.0, 0.02, 0.0, 0.06, 0.02, 0.0));
        let (cur, cur_depth) = scene.render(&cam, &t_wc, false, 0.0);
        let (nb, nb_depth) = scene.render(&cam, &t_wn, false, 0.0);
        let t_cn = t_wc.inverse() * t_wn;
        let out = splat(&nb, &nb_depth, &t_cn, &cam, &SplatParams::default()).unwrap();
        let mut n = 0;
        let mut bad_depth = 0;
        let mut err = 0.0f64;
        for (i, (a, b)) in out.image.pixels().zip(cur.pixels()).enumerate() {
            if out.holes[i] {
                continue;
            }
            n += 1;
            err += (a.0[1] as f64 - b.0[1] as f64).abs();
            let dz = (out.depth.as_raw()[i] - cur_depth.as_raw()[i]).abs();
            // Depth edges are dilated by up to one pixel (the bilinear footprint).
            if dz > 0.05 {
                bad_depth += 1;
            }
        }
        assert!(
            bad_depth * 20 < n,
            "{bad_depth} of {n} pixels with wrong depth"
        );
        let holes = out.holes.iter().filter(|&&h| h).count();
        assert!(
            n > 0 && holes > 0 && holes < out.holes.len() / 5,
            "holes {holes}"
        );
        let mean = err / n as f64;
        assert!(mean < 4.0, "mean abs error {mean}");
        // Without compensation the images differ much more.
        let raw: f64 = nb
            .pixels()
            .zip(cur.pixels())
            .map(|(a, b)| (a.0[1] as f64 - b.0[1] as f64).abs())
            .sum::<f64>()
            / n as f64;
        assert!(raw > 3.0 * mean, "raw {raw} vs warped {mean}");
    }

    #[test]
    fn paper_mode_skips_invalid_depth_reference_does_not() {
        let cam = small_camera();
        let img = RgbImage::from_pixel(cam.width, cam.height, Rgb([200, 200, 200]));
        let mut depth = FloatImage::from_pixel(cam.width, cam.height, image::Luma([2.0]));
        depth.put_pixel(10, 10, image::Luma([0.0]));
        let t = Se3::translation(0.0, 0.0, 0.1);
        let p = splat(&img, &depth, &t, &cam, &SplatParams::new(Mode::Paper)).unwrap();
        // The z = 0 pixel is dropped; nothing lands at K·t/t_z with an absurd weight.
        let r = splat(&img, &depth, &t, &cam, &SplatParams::new(Mode::Reference)).unwrap();
        let ci = (cam.cy.round() as usize) * cam.width as usize + cam.cx.round() as usize;
        assert!(!p.holes[ci]);
        assert!((p.depth.as_raw()[ci] - 2.1).abs() < 1e-3);
        // Reference: the invalid pixel lands near the principal point with depth 0.1 and the
        // largest weight, so it dominates the depth there.
        assert!(r.depth.as_raw()[ci] < 1.0, "{}", r.depth.as_raw()[ci]);
    }
}
