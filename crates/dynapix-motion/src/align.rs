//! Rotation refinement of a relative pose before splatting (new; spec §7.1 asks for pose
//! sources other than ground truth, whose errors the reference never faces). A rotation error
//! of the pose shifts the whole warped image almost uniformly (1° ≈ 9 px at 535 px focal
//! length), which would show up as motion everywhere. The source is splatted with the given
//! pose, the flow from the current image to the warped one is measured, and its median over
//! the covered pixels (movers are a minority) is removed by a small extra rotation of the
//! target camera about its x and y axes.

use dynapix_flow::FlowProvider;
use dynapix_geometry::{PinholeCamera, Se3};
use image::{GrayImage, RgbImage};
use nalgebra::{Translation3, UnitQuaternion};

use crate::gray::to_gray;
use crate::splat::{SplatParams, splat};
use crate::{FloatImage, Mode, MotionError};

fn median(v: &mut [f32]) -> f32 {
    dynapix_geometry::stats::upper_median_by(v, f32::total_cmp).unwrap_or(0.0)
}

/// Returns `t_ts` corrected by the rotation that cancels the median flow between `cur_gray`
/// and `src` warped into the target view. Iterates `iterations` times.
#[allow(clippy::too_many_arguments)]
pub fn refine_rotation(
    cur_gray: &GrayImage,
    src: &RgbImage,
    src_depth: &FloatImage,
    t_ts: &Se3,
    cam: &PinholeCamera,
    splat_params: &SplatParams,
    flow: &dyn FlowProvider,
    iterations: usize,
) -> Result<Se3, MotionError> {
    let sp = SplatParams {
        mode: Mode::Paper,
        ..splat_params.clone()
    };
    let mut t = *t_ts;
    for _ in 0..iterations {
        let w = splat(src, src_depth, &t, cam, &sp)?;
        let mut img = w.image.clone();
        // Holes get the current image so they carry no flow.
        let cur = cur_gray.as_raw();
        for (k, p) in img.pixels_mut().enumerate() {
            if w.holes[k] {
                let g = cur[k];
                *p = image::Rgb([g, g, g]);
            }
        }
        let f = flow.flow(cur_gray, &to_gray(&img))?;
        let (mut du, mut dv): (Vec<f32>, Vec<f32>) = f
            .data
            .iter()
            .zip(&w.holes)
            .filter(|&(_, &h)| !h)
            .map(|(d, _)| (d[0], d[1]))
            .unzip();
        if du.len() < 16 {
            break;
        }
        let (mu, mv) = (median(&mut du) as f64, median(&mut dv) as f64);
        // A rotation β about y shifts projections by fx·β in u; α about x by −fy·α in v.
        let beta = -mu / cam.fx;
        let alpha = mv / cam.fy;
        let delta = Se3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_euler_angles(alpha, beta, 0.0),
        );
        t = delta * t;
        if mu.abs() < 0.05 && mv.abs() < 0.05 {
            break;
        }
    }
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{BlockFlow, Scene, small_camera};

    #[test]
    fn a_rotation_error_is_removed() {
        let cam = small_camera();
        let scene = Scene::default();
        let t_wc = Se3::identity();
        let t_wn = Se3::translation(0.03, 0.0, 0.0);
        let (cur, _) = scene.render(&cam, &t_wc, false, 0.0);
        let (nb, nd) = scene.render(&cam, &t_wn, false, 0.0);
        let truth = t_wc.inverse() * t_wn;
        // 2° about y and 1° about x: several pixels of shift at 80 px focal length.
        let err = Se3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_euler_angles(1f64.to_radians(), 2f64.to_radians(), 0.0),
        );
        let noisy = err * truth;
        let flow = BlockFlow { radius: 5, half: 2 };
        let fixed = refine_rotation(
            &to_gray(&cur),
            &nb,
            &nd,
            &noisy,
            &cam,
            &SplatParams::default(),
            &flow,
            3,
        )
        .unwrap();
        let before = (noisy.rotation.inverse() * truth.rotation)
            .angle()
            .to_degrees();
        let after = (fixed.rotation.inverse() * truth.rotation)
            .angle()
            .to_degrees();
        assert!(before > 2.0 && after < 0.6, "{before}° → {after}°");
    }
}
