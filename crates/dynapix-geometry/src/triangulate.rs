//! Two-view linear triangulation (DLT with SVD), as ORB-SLAM2's local mapping uses to create
//! map points from matches between neighbouring keyframes (spec §6.5), plus the checks that
//! follow it (positive depth in both views, reprojection χ²).

use crate::camera::PinholeCamera;
use crate::se3::Se3;
use nalgebra::{Matrix3x4, Matrix4, RowVector4, Vector2, Vector3};

/// Homogeneous coordinates with |w| below this (relative to the vector's norm) are points at
/// infinity and cannot be triangulated.
const MIN_HOMOGENEOUS_W: f64 = 1e-12;

/// Normalised image coordinates `((u − cx)/fx, (v − cy)/fy)` of an undistorted pixel.
pub fn normalize(camera: &PinholeCamera, uv: &Vector2<f64>) -> Vector2<f64> {
    Vector2::new(
        (uv.x - camera.cx) / camera.fx,
        (uv.y - camera.cy) / camera.fy,
    )
}

/// The 3×4 matrix `[R | t]` of `T_cw`.
fn projection_matrix(t_cw: &Se3) -> Matrix3x4<f64> {
    let mut p = Matrix3x4::zeros();
    p.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(t_cw.rotation.to_rotation_matrix().matrix());
    p.set_column(3, &t_cw.translation.vector);
    p
}

/// Linear triangulation of one point from two views.
///
/// `x1`, `x2` are normalised image coordinates (see [`normalize`]) in the cameras with poses
/// `t1_cw`, `t2_cw`. Each view contributes the rows `x·P₃ − P₁` and `y·P₃ − P₂`; the point is
/// the right singular vector of the smallest singular value. Returns `None` for points at
/// infinity (parallel rays) or non-finite input. It does not test the depth: use
/// [`in_front_of_both`].
pub fn triangulate_dlt(
    t1_cw: &Se3,
    t2_cw: &Se3,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> Option<Vector3<f64>> {
    let p1 = projection_matrix(t1_cw);
    let p2 = projection_matrix(t2_cw);
    let row = |p: &Matrix3x4<f64>, r: usize| -> RowVector4<f64> { p.row(r).into_owned() };
    let a = Matrix4::from_rows(&[
        x1.x * row(&p1, 2) - row(&p1, 0),
        x1.y * row(&p1, 2) - row(&p1, 1),
        x2.x * row(&p2, 2) - row(&p2, 0),
        x2.y * row(&p2, 2) - row(&p2, 1),
    ]);
    if !a.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = a.svd(false, true);
    let vt = svd.v_t?;
    let (k, _) = svd.singular_values.argmin();
    let h = vt.row(k);
    if h[3].abs() <= MIN_HOMOGENEOUS_W * h.norm() {
        return None;
    }
    let x = Vector3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]);
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Depth (camera z) of world point `x` in the camera with pose `t_cw`.
pub fn depth(t_cw: &Se3, x: &Vector3<f64>) -> f64 {
    (t_cw.rotation * x + t_cw.translation.vector).z
}

/// True when `x` has positive depth in both cameras (ORB-SLAM2 rejects other triangulations).
pub fn in_front_of_both(t1_cw: &Se3, t2_cw: &Se3, x: &Vector3<f64>) -> bool {
    depth(t1_cw, x) > 0.0 && depth(t2_cw, x) > 0.0
}

/// Squared pixel distance between `uv` and the projection of world point `x` (`None` behind
/// the camera); compare with `χ²·σ²` (5.991 for mono) as local mapping does.
pub fn reprojection_error2(
    camera: &PinholeCamera,
    t_cw: &Se3,
    x: &Vector3<f64>,
    uv: &Vector2<f64>,
) -> Option<f64> {
    let xc = t_cw.rotation * x + t_cw.translation.vector;
    if xc.z <= 0.0 {
        return None;
    }
    let u = camera.fx * xc.x / xc.z + camera.cx;
    let v = camera.fy * xc.y / xc.z + camera.cy;
    Some((u - uv.x).powi(2) + (v - uv.y).powi(2))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn poses() -> (Se3, Se3) {
        let t1 = Se3::from_parts(
            Translation3::new(0.1, 0.0, -0.2),
            UnitQuaternion::from_euler_angles(0.02, 0.05, -0.01),
        );
        let t2 = Se3::from_parts(
            Translation3::new(-0.2, 0.05, -0.1),
            UnitQuaternion::from_euler_angles(-0.03, 0.1, 0.02),
        );
        (t1, t2)
    }

    fn pixel(cam: &PinholeCamera, t: &Se3, x: &Vector3<f64>) -> Vector2<f64> {
        let xc = t.rotation * x + t.translation.vector;
        Vector2::new(cam.fx * xc.x / xc.z + cam.cx, cam.fy * xc.y / xc.z + cam.cy)
    }

    #[test]
    fn exact_on_noise_free_data() {
        let cam = PinholeCamera::tum_fr3();
        let (t1, t2) = poses();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200 {
            let x = Vector3::new(
                rng.random_range(-1.5..1.5),
                rng.random_range(-1.0..1.0),
                rng.random_range(1.0..8.0),
            );
            let x1 = normalize(&cam, &pixel(&cam, &t1, &x));
            let x2 = normalize(&cam, &pixel(&cam, &t2, &x));
            let Some(y) = triangulate_dlt(&t1, &t2, &x1, &x2) else {
                panic!("no point for {x:?}");
            };
            assert!((y - x).norm() < 1e-8 * x.norm().max(1.0), "{x:?} -> {y:?}");
            assert!(in_front_of_both(&t1, &t2, &y));
            let e = reprojection_error2(&cam, &t1, &y, &pixel(&cam, &t1, &x));
            assert!(e.is_some_and(|e| e < 1e-12));
        }
    }

    #[test]
    fn noise_gives_small_error_and_behind_points_are_detected() {
        let cam = PinholeCamera::tum_fr3();
        let (t1, t2) = poses();
        let x = Vector3::new(0.3, -0.2, 3.0);
        let p1 = pixel(&cam, &t1, &x) + Vector2::new(0.5, -0.3);
        let p2 = pixel(&cam, &t2, &x) + Vector2::new(-0.4, 0.2);
        let y = triangulate_dlt(&t1, &t2, &normalize(&cam, &p1), &normalize(&cam, &p2));
        assert!(y.is_some_and(|y| (y - x).norm() < 0.1), "{y:?}");
        // Rays that meet behind the cameras triangulate, but fail the depth check.
        let behind = Vector3::new(0.3, -0.2, -3.0);
        let x1 = {
            let xc = t1.rotation * behind + t1.translation.vector;
            Vector2::new(xc.x / xc.z, xc.y / xc.z)
        };
        let x2 = {
            let xc = t2.rotation * behind + t2.translation.vector;
            Vector2::new(xc.x / xc.z, xc.y / xc.z)
        };
        let y = triangulate_dlt(&t1, &t2, &x1, &x2);
        assert!(y.is_some_and(|y| !in_front_of_both(&t1, &t2, &y)));
        assert_eq!(reprojection_error2(&cam, &t1, &behind, &p1), None);
    }

    #[test]
    fn parallel_rays_give_no_point() {
        // Two cameras side by side with the same bearing: the rays meet at infinity.
        let t1 = Se3::identity();
        let t2 = Se3::from_parts(
            Translation3::new(-0.5, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        let x = Vector2::new(0.1, 0.05);
        assert_eq!(triangulate_dlt(&t1, &t2, &x, &x), None);
        // A tiny disparity gives a far but finite point.
        let far = triangulate_dlt(&t1, &t2, &x, &Vector2::new(0.1 - 1e-4, 0.05));
        assert!(far.is_some_and(|y| y.z > 1000.0), "{far:?}");
    }
}
