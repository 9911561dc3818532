//! The flow of a frame pair reversed through the fitted motion ([`reverse_flow`]), so one
//! flow per pair serves both directions.

use dynapix_flow::FlowField;
use dynapix_geometry::{PixelRays, Se3};

use super::pair::check_flow;
use super::params::RigidityParams;
use crate::{FloatImage, MotionError, check_size};

/// The flow b → a on b's pixel grid from the flow a → b: each pixel x of frame a with depth
/// above [`RigidityParams::min_depth`] and a ray whose target `x + f(x)` lies inside the image
/// gives the flow `−f(x)` to the four pixels around its target (so a stretching flow leaves
/// no holes). Where several pixels of a reach one pixel of b, the one nearest camera b after
/// `motion` (a → b) wins, as in a depth buffer: depths compared in f32, those at or behind
/// camera b as 0, ties to the first pixel in row order. Pixels of b that no pixel of a
/// reaches get NaN flow, which [`dense_residual`](super::dense_residual) treats as no
/// correspondence.
pub fn reverse_flow(
    flow: &FlowField,
    depth_a: &FloatImage,
    rays: &PixelRays,
    motion: &Se3,
    params: &RigidityParams,
) -> Result<FlowField, MotionError> {
    let cam = rays.camera();
    let size = (cam.width, cam.height);
    check_size("depth of frame a", size, depth_a.dimensions())?;
    check_flow(flow, size)?;
    let (w, h) = (cam.width as usize, cam.height as usize);
    // Only the depth after the motion matters: the third row of R·p + t.
    let rm = motion.rotation.to_rotation_matrix();
    let m = rm.matrix();
    let (r20, r21, r22, tz) = (m[(2, 0)], m[(2, 1)], m[(2, 2)], motion.translation.vector.z);
    let (xmax, ymax) = ((w.max(1) - 1) as f64, (h.max(1) - 1) as f64);
    // The depth buffer: per pixel of b, the depth (f32) and the index of the nearest pixel
    // of a so far in one key, `depth bits << 32 | index`, so the smallest key is the nearest
    // pixel and, among equal depths, the first. A depth at or below zero (behind camera b)
    // counts as 0: the bits of a non-negative f32 order like the numbers.
    let mut nearest = vec![u64::MAX; w * h];
    let min_depth = params.min_depth;
    for y in 0..h {
        let row = y * w..(y + 1) * w;
        let (za, ra, fa) = (
            &depth_a.as_raw()[row.clone()],
            &rays.all()[row.clone()],
            &flow.data[row],
        );
        for (x, ((&z, ray), f)) in za.iter().zip(ra).zip(fa).enumerate() {
            let z = z as f64;
            let (u2, v2) = (x as f64 + f[0] as f64, y as f64 + f[1] as f64);
            let valid = !(z.is_nan() || z <= min_depth)
                & ray[0].is_finite()
                & (0.0..=xmax).contains(&u2)
                & (0.0..=ymax).contains(&v2);
            if !valid {
                continue;
            }
            let zb = r20 * (ray[0] * z) + r21 * (ray[1] * z) + r22 * z + tz;
            let zb = if zb > 0.0 { zb as f32 } else { 0.0 };
            let key = ((zb.to_bits() as u64) << 32) | (y * w + x) as u64;
            // The four pixels around the target: a stretching flow leaves no holes.
            // SAFETY: 0 ≤ u2 ≤ xmax and 0 ≤ v2 ≤ ymax (checked above), so both truncate
            // into u32 (a single instruction, where `as` would add saturation checks).
            let (u0, v0) = unsafe {
                (
                    u2.to_int_unchecked::<u32>() as usize,
                    v2.to_int_unchecked::<u32>() as usize,
                )
            };
            let (u1, v1) = ((u0 + 1).min(w - 1), (v0 + 1).min(h - 1));
            for t in [v0 * w + u0, v0 * w + u1, v1 * w + u0, v1 * w + u1] {
                let n = &mut nearest[t];
                *n = (*n).min(key);
            }
        }
    }
    let data = nearest
        .iter()
        .map(|&key| match flow.data.get((key & 0xffff_ffff) as usize) {
            Some(f) if key != u64::MAX => [-f[0], -f[1]],
            _ => [f32::NAN; 2],
        })
        .collect();
    Ok(FlowField {
        width: cam.width,
        height: cam.height,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::RocAccumulator;
    use crate::rigidity::{fixtures::*, *};
    use crate::testutil::small_camera;

    #[test]
    fn the_reversed_flow_of_a_translating_camera_has_no_residual() {
        // The plane of the test above, seen from camera j: the flow j → i is the constant
        // −du, so the reversed flow is −du wherever a pixel of i lands, and the inverse of the
        // fit explains it.
        let (cam, rays, depth, du, flow) = translating_plane();
        let (w, h) = (cam.width, cam.height);
        let params = RigidityParams::default();
        let motion = se3([0.0; 3], [0.05, 0.0, 0.0]);
        let narrow = FloatImage::new(w - 1, h);
        assert!(matches!(
            reverse_flow(&flow, &narrow, &rays, &motion, &params),
            Err(MotionError::SizeMismatch { .. })
        ));
        let g = reverse_flow(&flow, &depth, &rays, &motion, &params).unwrap();
        for y in 0..h {
            for x in 0..w {
                let v = g.get(x, y);
                // Pixel x of j is reached from x − du of i, rounded: from x ≥ round(du).
                if x as f32 >= du.round() {
                    assert_eq!(v, [-du, -0.0], "({x}, {y})");
                } else {
                    assert!(v[0].is_nan() && v[1].is_nan(), "({x}, {y}): {v:?}");
                }
            }
        }
        let r = dense_residual(&depth, &depth, &g, &rays, &motion.inverse(), &params).unwrap();
        let defined: Vec<f32> = r.iter().copied().filter(|v| !v.is_nan()).collect();
        assert!(
            defined.len() > (w as usize - 10) * h as usize,
            "{}",
            defined.len()
        );
        assert!(defined.iter().all(|&v| v < 0.05));
    }

    #[test]
    fn the_reversed_flow_keeps_the_nearer_of_two_pixels_landing_together() {
        let cam = small_camera();
        let rays = camera_rays(&cam);
        let (w, h) = (cam.width, cam.height);
        let params = RigidityParams::default();
        // Pixel (10, 5) moves right by one onto (11, 5), which stays put.
        let mut flow = FlowField::constant(w, h, [0.0, 0.0]);
        flow.data[5 * w as usize + 10] = [1.0, 0.0];
        let at = |near_moves: bool| {
            let mut depth = FloatImage::from_pixel(w, h, image::Luma([3.0]));
            let (mover, still) = if near_moves { (1.0, 2.0) } else { (2.0, 1.0) };
            depth.put_pixel(10, 5, image::Luma([mover]));
            depth.put_pixel(11, 5, image::Luma([still]));
            let g = reverse_flow(&flow, &depth, &rays, &Se3::identity(), &params).unwrap();
            (g.get(10, 5), g.get(11, 5))
        };
        // Each pixel covers the four pixels around its target, (11, 5) to (12, 6) for both;
        // the vacated (10, 5) is covered by its still neighbours (9, 5), (10, 4), (9, 4).
        let (left, right) = at(true);
        assert_eq!(left, [-0.0, -0.0]);
        assert_eq!(right, [-1.0, -0.0]);
        let (left, right) = at(false);
        assert_eq!(left, [-0.0, -0.0]);
        assert_eq!(right, [-0.0, -0.0]);
    }

    #[test]
    fn the_reversed_flow_of_a_stretching_flow_has_no_holes() {
        // Frame j sees the image of i stretched by 1.5 across: target x' = 1.5·x. Rounded
        // targets would skip every third pixel; the four-pixel footprint covers them all.
        let cam = small_camera();
        let rays = camera_rays(&cam);
        let (w, h) = (cam.width, cam.height);
        let params = RigidityParams::default();
        let depth = FloatImage::from_pixel(w, h, image::Luma([2.0]));
        let mut flow = FlowField::constant(w, h, [0.0, 0.0]);
        for (k, f) in flow.data.iter_mut().enumerate() {
            *f = [0.5 * (k % w as usize) as f32, 0.0];
        }
        let g = reverse_flow(&flow, &depth, &rays, &Se3::identity(), &params).unwrap();
        for y in 0..h {
            for x in 0..w {
                assert!(!g.get(x, y)[0].is_nan(), "hole at ({x}, {y})");
            }
        }
    }

    #[test]
    fn the_backward_residual_separates_walkers_like_the_frames_own_flow() {
        // The later frame b of a pair (a, b) three or four frames apart: its P from its own
        // flow b → a, and from the flow a → b turned around (shared pairs).
        let s = synth();
        let params = RigidityParams::default();
        let frame = |i: usize| RigidFrame {
            gray: &s.frames[i].0,
            depth: &s.frames[i].1,
            offset: 0,
        };
        let dis = params.flow_for_width(s.cam.width);
        let size = (s.cam.width, s.cam.height);
        let mut own = RocAccumulator::new(0.5);
        let mut shared = RocAccumulator::new(0.5);
        for (a, b) in [(0, 3), (0, 4), (1, 4)] {
            let mask = s.frames[b].2.as_raw();
            let add = |roc: &mut RocAccumulator, p: &FloatImage| add_fast_movers(roc, p, mask);
            let direct =
                pair_residuals(&frame(b), &frame(a), &s.cam, &dis, &params, false).unwrap();
            assert!(direct.backward.is_none());
            let maps = rigidity_from_pairs(vec![(-4, direct.fit, direct.forward)], size, &params);
            add(&mut own, &maps.unwrap().p);
            let pair = pair_residuals(&frame(a), &frame(b), &s.cam, &dis, &params, true).unwrap();
            let maps =
                rigidity_from_pairs(vec![(-4, pair.inverse_fit(), pair.backward)], size, &params);
            let maps = maps.unwrap();
            assert!(maps.fits.iter().all(|f| f.is_ok()));
            add(&mut shared, &maps.p);
        }
        let (a_own, a_shared) = (own.auc().unwrap(), shared.auc().unwrap());
        eprintln!(
            "walkers against the static scene: AUC {a_own:.3} own flow, {a_shared:.3} shared"
        );
        assert!(a_shared > 0.85, "{a_shared}");
        assert!(a_shared > a_own - 0.03, "{a_shared} against {a_own}");
    }
}
