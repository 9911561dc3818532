//! One frame end to end (paper §3.1 "Motion Probability", Eq. 8; spec §1.8 and §1.11):
//! `P = D ⊙ M`, with the ablations of the paper (no movable term: D = 1; no moving term:
//! M = 1). The 16-bit file encoding of the static weight `(1 − P)·1000` lives in
//! `dynapix_io::weights` (one codec).

use dynapix_flow::FlowProvider;
use dynapix_geometry::PinholeCamera;
use image::Luma;
use serde::{Deserialize, Serialize};

use crate::movable::{MovableParams, movable};
use crate::moving::{FrameImages, MovingParams, Neighbour, moving_term};
use crate::splat::SplatParams;
use crate::{FloatImage, Mode, MotionError, Variant, check_size};

/// All parameters of the motion probability. `Default` = TUM variant, paper mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MotionParams {
    /// Reference or paper behaviour.
    pub mode: Mode,
    /// Reference constant set.
    pub variant: Variant,
    /// Neighbour frame offsets J (both signs listed, e.g. `[-1, 1]`).
    pub offsets: Vec<i64>,
    /// Movable term.
    pub movable: MovableParams,
    /// View synthesis.
    pub splat: SplatParams,
    /// Moving term.
    pub moving: MovingParams,
    /// Ablation: false sets D = 1.
    pub use_movable: bool,
    /// Ablation: false sets M = 1.
    pub use_moving: bool,
}

impl Default for MotionParams {
    fn default() -> Self {
        Self::new(Variant::Tum, Mode::Paper)
    }
}

impl MotionParams {
    /// The constants of `variant` in `mode` (neighbours ±1 on TUM, ±2 on GRADE).
    pub fn new(variant: Variant, mode: Mode) -> Self {
        let j = match variant {
            Variant::Tum => 1,
            Variant::Grade => 2,
        };
        Self {
            mode,
            variant,
            offsets: vec![-j, j],
            movable: MovableParams::new(variant, mode),
            splat: SplatParams::new(mode),
            moving: MovingParams::new(variant, mode),
            use_movable: true,
            use_moving: true,
        }
    }
}

/// The maps of one frame.
#[derive(Clone, Debug)]
pub struct MotionMaps {
    /// Motion probability P = D·M.
    pub p: FloatImage,
    /// Movable term D (all ones when ablated).
    pub d: FloatImage,
    /// Moving term M (all ones when ablated).
    pub m: FloatImage,
}

/// Computes the motion probability of `cur` from its neighbours.
pub fn motion_probability(
    cur: &FrameImages,
    neighbours: &[Neighbour],
    cam: &PinholeCamera,
    flow: &dyn FlowProvider,
    params: &MotionParams,
) -> Result<MotionMaps, MotionError> {
    let size = (cam.width, cam.height);
    check_size("current image", size, cur.rgb.dimensions())?;
    check_size("current depth", size, cur.depth.dimensions())?;
    check_size("current background", size, cur.background.dimensions())?;
    check_size(
        "current background depth",
        size,
        cur.background_depth.dimensions(),
    )?;
    for (k, nb) in neighbours.iter().enumerate() {
        let what = |s: &str| format!("neighbour {k} {s}");
        check_size(&what("image"), size, nb.frame.rgb.dimensions())?;
        check_size(&what("depth"), size, nb.frame.depth.dimensions())?;
        check_size(&what("background"), size, nb.frame.background.dimensions())?;
        check_size(
            &what("background depth"),
            size,
            nb.frame.background_depth.dimensions(),
        )?;
    }
    let ones = || FloatImage::from_pixel(size.0, size.1, Luma([1.0]));
    let (d, m) = rayon::join(
        || -> Result<FloatImage, MotionError> {
            if params.use_movable {
                let _stage =
                    tracing::info_span!(target: "dynapix::stage", "paper: movable term").entered();
                Ok(movable(cur.rgb, cur.background, cur.depth, &params.movable)?.d)
            } else {
                Ok(ones())
            }
        },
        || {
            if params.use_moving {
                moving_term(cur, neighbours, cam, &params.splat, flow, &params.moving)
            } else {
                Ok(ones())
            }
        },
    );
    let (d, m) = (d?, m?);
    let mut p = FloatImage::new(size.0, size.1);
    for ((o, a), b) in p.iter_mut().zip(d.iter()).zip(m.iter()) {
        *o = (a * b).clamp(0.0, 1.0);
    }
    Ok(MotionMaps { p, d, m })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{BlockFlow, Scene, small_camera};
    use dynapix_geometry::Se3;

    #[test]
    fn ablations_and_product() {
        let cam = small_camera();
        let scene = Scene::default();
        let t0 = Se3::identity();
        let t1 = Se3::translation(0.04, 0.0, 0.0);
        let (rgb0, d0) = scene.render(&cam, &t0, true, -0.2);
        let (bg0, bd0) = scene.render(&cam, &t0, false, 0.0);
        let (rgb1, d1) = scene.render(&cam, &t1, true, -0.1);
        let (bg1, bd1) = scene.render(&cam, &t1, false, 0.0);
        let cur = FrameImages {
            rgb: &rgb0,
            depth: &d0,
            background: &bg0,
            background_depth: &bd0,
        };
        let nb = [Neighbour {
            frame: FrameImages {
                rgb: &rgb1,
                depth: &d1,
                background: &bg1,
                background_depth: &bd1,
            },
            t_cn: t0.inverse() * t1,
        }];
        let flow = BlockFlow { radius: 5, half: 2 };
        let mut params = MotionParams::new(Variant::Tum, Mode::Paper);
        let full = motion_probability(&cur, &nb, &cam, &flow, &params).unwrap();
        for ((p, d), m) in full.p.iter().zip(full.d.iter()).zip(full.m.iter()) {
            assert!((p - d * m).abs() < 1e-6);
        }
        params.use_moving = false;
        let no_m = motion_probability(&cur, &nb, &cam, &flow, &params).unwrap();
        assert!(no_m.m.iter().all(|&v| v == 1.0));
        assert_eq!(no_m.p, full.d);
        params.use_moving = true;
        params.use_movable = false;
        let no_d = motion_probability(&cur, &nb, &cam, &flow, &params).unwrap();
        assert!(no_d.d.iter().all(|&v| v == 1.0));
        assert_eq!(no_d.p, full.m);
        // The mover (depth 1.5 m) has a much higher probability than the rest.
        let (mut sin, mut nin, mut sout, mut nout) = (0.0, 0, 0.0, 0);
        for (p, z) in full.p.iter().zip(d0.iter()) {
            if (z - 1.5).abs() < 1e-3 {
                sin += p;
                nin += 1;
            } else {
                sout += p;
                nout += 1;
            }
        }
        let (a, b) = (sin / nin as f32, sout / nout as f32);
        assert!(a > 0.4 && b < 0.05, "{a} vs {b}");
    }
}
