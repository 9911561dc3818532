//! Test fixtures shared by the tests of the submodules.

use std::sync::Arc;

use dynapix_flow::FlowField;
use dynapix_geometry::{PinholeCamera, PixelRays, Se3};
use image::GrayImage;
use nalgebra::{Point3, Vector3};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::params::RigidityParams;
use super::probability::{camera_rays, rigidity_probability};
use super::{RigidFrame, RigidityMaps};
use crate::FloatImage;
use crate::metrics::RocAccumulator;
use crate::testutil::small_camera;
use nalgebra::{Translation3, UnitQuaternion};
use rand::Rng;
use std::sync::OnceLock;

pub(super) fn se3(axis_angle: [f64; 3], t: [f64; 3]) -> Se3 {
    Se3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_scaled_axis(Vector3::from(axis_angle)),
    )
}

/// Rotation angle (rad) and translation distance between two motions.
pub(super) fn distance(a: &Se3, b: &Se3) -> (f64, f64) {
    let d = a.inverse() * b;
    (
        d.rotation.angle(),
        (a.translation.vector - b.translation.vector).norm(),
    )
}

/// A depth map with holes (0 and NaN) among depths of 0.05–4 m.
pub(super) fn random_depth(rng: &mut ChaCha8Rng, w: u32, h: u32) -> FloatImage {
    FloatImage::from_fn(w, h, |_, _| {
        image::Luma([match rng.random_range(0..10) {
            0 => 0.0,
            1 => f32::NAN,
            _ => rng.random_range(0.05f32..4.0),
        }])
    })
}

/// Points in front of the camera inside a 640×480 frustum, moved by `motion`
/// and perturbed by at most half a pixel and one σ_z.
pub(super) fn scene_pairs(
    rng: &mut ChaCha8Rng,
    n: usize,
    motion: &Se3,
    cam: &PinholeCamera,
    params: &RigidityParams,
) -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
    let mut src = Vec::with_capacity(n);
    let mut dst = Vec::with_capacity(n);
    while src.len() < n {
        let z = rng.random_range(1.0..4.0);
        let a = Point3::new(
            rng.random_range(-0.55..0.55) * z,
            rng.random_range(-0.4..0.4) * z,
            z,
        );
        let b = motion * a;
        let sz = params.sigma_z_quadratic * b.z * b.z + params.sigma_z_constant;
        let bz = b.z + rng.random_range(-1.0..1.0) * sz;
        let bx = b.x / b.z + rng.random_range(-0.5..0.5) / cam.fx;
        let by = b.y / b.z + rng.random_range(-0.5..0.5) / cam.fy;
        src.push(a);
        dst.push(Point3::new(bx * bz, by * bz, bz));
    }
    (src, dst)
}

/// A fronto-parallel plane at 2 m seen by a camera shifted by 5 cm along x: the camera,
/// its rays, the depth of both frames, the constant flow `du` px and that flow.
pub(super) fn translating_plane() -> (PinholeCamera, Arc<PixelRays>, FloatImage, f32, FlowField) {
    let cam = small_camera();
    let rays = camera_rays(&cam);
    let depth = FloatImage::from_pixel(cam.width, cam.height, image::Luma([2.0]));
    let du = (cam.fx * 0.05 / 2.0) as f32;
    let flow = FlowField::constant(cam.width, cam.height, [du, 0.0]);
    (cam, rays, depth, du, flow)
}

/// Frames 60-64 of a 320×240 `walking_xyz` synthetic sequence (a walker crosses the view
/// while another sits down): grey image, depth (m) and motion mask, rendered once for all
/// tests. The mask marks mover pixels that move more than 2 cm to the previous or next
/// frame 255 and slower mover pixels 128: a one-frame cue at this resolution cannot be
/// expected to see a few millimetres of motion (at 2 m, 2 cm are 2.7 px), so the slow ones
/// are left out of the score.
pub(super) struct Synth {
    pub(super) cam: PinholeCamera,
    pub(super) frames: Vec<(GrayImage, FloatImage, GrayImage)>,
}

pub(super) const SYNTH_FRAMES: usize = 5;

pub(super) fn synth() -> &'static Synth {
    static S: OnceLock<Synth> = OnceLock::new();
    S.get_or_init(|| {
        let full = PinholeCamera::tum_fr3();
        let s = 320.0 / full.width as f64;
        let cam = PinholeCamera::new(320, 240, full.fx * s, full.fy * s, full.cx * s, full.cy * s);
        let params = dynapix_synth::SynthParams {
            preset: dynapix_synth::Preset::WalkingXyz,
            frames: 100,
            seed: 0,
            scene: dynapix_synth::SceneParams::for_width(cam.width),
            camera: cam.clone(),
            moving_threshold: 0.02,
            ..dynapix_synth::SynthParams::default()
        };
        let seq = dynapix_synth::Sequence::new(params).expect("sequence");
        let frames = (60..60 + SYNTH_FRAMES)
            .into_par_iter()
            .map(|i| {
                let (f, _) = seq.frame(i, None);
                let depth = f.depth_metres();
                (crate::moving::to_gray(&f.rgb), depth, f.mask)
            })
            .collect();
        Synth { cam, frames }
    })
}

pub(super) fn synth_maps(k: usize, params: &RigidityParams) -> RigidityMaps {
    let s = synth();
    let frame = |i: usize| RigidFrame {
        gray: &s.frames[i].0,
        depth: &s.frames[i].1,
        offset: i as i64 - k as i64,
    };
    let nbs = [frame(k - 1), frame(k + 1)];
    rigidity_probability(&frame(k), &nbs, &s.cam, params).expect("maps")
}

/// P of the fast movers (mask 255) against the static scene (0) into `roc`; slow mover
/// pixels (128) left out.
pub(super) fn add_fast_movers(roc: &mut RocAccumulator, p: &FloatImage, mask: &[u8]) {
    let (p, pos): (Vec<f32>, Vec<bool>) = p
        .iter()
        .zip(mask)
        .filter(|(_, m)| **m != 128)
        .map(|(p, m)| (*p, *m == 255))
        .unzip();
    roc.add(&p, &pos);
}

pub(super) fn mean_where(p: &FloatImage, mask: &[bool]) -> f64 {
    let (s, n) = p
        .iter()
        .zip(mask)
        .filter(|(_, m)| **m)
        .fold((0.0, 0usize), |(s, n), (v, _)| (s + *v as f64, n + 1));
    s / n.max(1) as f64
}
