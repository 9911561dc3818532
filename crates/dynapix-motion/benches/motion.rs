//! Speed of the motion-probability stages on real 640×480 frames (TUM fr1_xyz from
//! `../shared/data`; skipped with a message when the data is absent):
//! `cargo bench -p dynapix-motion --bench motion`.

use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use dynapix_flow::FlowProvider;
use dynapix_flow::dis::{DisFlow, Preset};
use dynapix_geometry::PinholeCamera;
use dynapix_motion::background::{ReconstructParams, Source, reconstruct_background};
use dynapix_motion::moving::to_gray;
use dynapix_motion::rigidity::{
    RigidityParams, camera_rays, correspondences, dense_residual, fit_rigid_motion, reverse_flow,
};
use dynapix_motion::static_depth::{
    DepthView, StaticDepthParams, WorkingDepth, geometric_term, static_depth,
};
use dynapix_motion::{
    FrameImages, Mode, MotionParams, Neighbour, SplatParams, Variant, motion_probability, movable,
    splat,
};

fn data_dir() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz"
    ))
}

fn bench(c: &mut Criterion) {
    let dir = data_dir();
    let Ok(list) = dynapix_io::tum::read_list(dir.join("rgb.txt")) else {
        eprintln!("skipping: {} not found", dir.display());
        return;
    };
    let Ok(dlist) = dynapix_io::tum::read_list(dir.join("depth.txt")) else {
        eprintln!("skipping: no depth.txt");
        return;
    };
    let assoc = dynapix_io::tum::associate_lists(&list, &dlist, 0.0, 0.02);
    let Ok(traj) = dynapix_io::camera_trajectory(dir.join("groundtruth.txt")) else {
        eprintln!("skipping: no groundtruth.txt");
        return;
    };
    let cam = PinholeCamera::new(640, 480, 517.306408, 516.469215, 318.643040, 255.313989);
    let frames: Vec<_> = assoc
        .iter()
        .skip(20)
        .take(31)
        .filter_map(|a| {
            let rgb = dynapix_io::images::read_rgb(dir.join(&a.rgb)).ok()?;
            let depth = dynapix_io::images::read_depth(dir.join(&a.depth), 5000.0).ok()?;
            let pose = traj.interpolate(a.t_rgb, 0.05)?;
            Some((rgb, depth, pose))
        })
        .collect();
    if frames.len() < 31 {
        eprintln!("skipping: too few frames with poses");
        return;
    }
    let c0 = 15;
    let (rgb, depth, t_wc) = &frames[c0];
    let bg = &frames[c0 + 3].0; // any other frame stands in for a background image
    let t_cn = t_wc.inverse() * frames[c0 + 1].2;
    let mut g = c.benchmark_group("motion_640x480");
    g.sample_size(10);
    let mp = dynapix_motion::MovableParams::default();
    g.bench_function("to_gray", |b| {
        b.iter(|| dynapix_motion::moving::to_gray(std::hint::black_box(rgb)))
    });
    g.bench_function("movable", |b| {
        b.iter(|| movable(rgb, bg, depth, &mp).unwrap())
    });
    for mode in [Mode::Paper, Mode::Reference] {
        let sp = SplatParams::new(mode);
        g.bench_function(format!("splat_{mode:?}"), |b| {
            b.iter(|| splat(&frames[c0 + 1].0, &frames[c0 + 1].1, &t_cn, &cam, &sp).unwrap())
        });
    }
    let ga = to_gray(rgb);
    let gb = to_gray(&frames[c0 + 1].0);
    for preset in [Preset::Ultrafast, Preset::Fast, Preset::Medium] {
        let flow = DisFlow::with_preset(preset);
        g.bench_function(format!("dis_{preset:?}"), |b| {
            b.iter(|| flow.flow(&ga, &gb).unwrap())
        });
    }
    let view = |k: usize| FrameImages {
        rgb: &frames[k].0,
        depth: &frames[k].1,
        background: &frames[k].0,
        background_depth: &frames[k].1,
    };
    let cur = FrameImages {
        background: bg,
        ..view(c0)
    };
    let nbs: Vec<Neighbour> = [c0 - 1, c0 + 1]
        .iter()
        .map(|&k| Neighbour {
            frame: view(k),
            t_cn: t_wc.inverse() * frames[k].2,
        })
        .collect();
    for (mode, preset) in [
        (Mode::Paper, Preset::Fast),
        (Mode::Paper, Preset::Medium),
        (Mode::Reference, Preset::Fast),
    ] {
        let flow = DisFlow::with_preset(preset);
        let params = MotionParams::new(Variant::Tum, mode);
        g.bench_function(format!("frame_{mode:?}_{preset:?}"), |b| {
            b.iter(|| motion_probability(&cur, &nbs, &cam, &flow, &params).unwrap())
        });
    }
    let rp = ReconstructParams::default();
    let sources: Vec<Source> = rp
        .offsets()
        .iter()
        .map(|&o| {
            let k = (c0 as i64 + o) as usize;
            Source {
                rgb: &frames[k].0,
                depth: &frames[k].1,
                t_ts: t_wc.inverse() * frames[k].2,
            }
        })
        .collect();
    g.bench_function("reconstruct_background_10_sources", |b| {
        b.iter(|| reconstruct_background(rgb, depth, &sources, &cam, &rp, None).unwrap())
    });
    // The geometric cue as the default DynaPix runs it: 24 views at a 320-pixel working
    // width, the camera's lens distortion modelled (TUM fr1's coefficients).
    let mut dcam = cam.clone();
    dcam.dist = [0.262383, -0.953104, -0.005358, 0.002628, 1.163314];
    let sdp = StaticDepthParams::default();
    let working: Vec<WorkingDepth> = frames
        .iter()
        .map(|f| WorkingDepth::new(&f.1, &sdp))
        .collect();
    let views: Vec<DepthView<'_>> = (0..frames.len())
        .filter(|&k| k != c0)
        .take(sdp.max_views)
        .map(|k| DepthView {
            depth: &working[k],
            t_cs: t_wc.inverse() * frames[k].2,
        })
        .collect();
    g.bench_function("static_depth_24_views", |b| {
        b.iter(|| static_depth(&dcam, &views, &sdp).unwrap())
    });
    // The same views through a pinhole camera (synthetic sequences, rectified cameras).
    g.bench_function("static_depth_24_views_pinhole", |b| {
        b.iter(|| static_depth(&cam, &views, &sdp).unwrap())
    });
    let sd = static_depth(&dcam, &views, &sdp).unwrap();
    g.bench_function("geometric_term", |b| {
        b.iter(|| geometric_term(&working[c0], &sd, &sdp).unwrap())
    });
    // The rigidity cue's stages on the pair (c0, c0 + 2) with the default parameters: the
    // flow at its working width, the correspondences and the RANSAC fit, the dense residual.
    let rp = RigidityParams::default();
    let rays = camera_rays(&cam);
    let (g0, g2) = (to_gray(rgb), to_gray(&frames[c0 + 2].0));
    let d2 = &frames[c0 + 2].1;
    let dis = rp.flow_for_width(cam.width);
    let f02 = dis.flow(&g0, &g2).unwrap();
    g.bench_function("rigidity_flow", |b| b.iter(|| dis.flow(&g0, &g2).unwrap()));
    let corr = correspondences(depth, d2, &f02, &rays, &rp).unwrap();
    g.bench_function("rigidity_fit", |b| {
        b.iter(|| {
            let corr = correspondences(depth, d2, &f02, &rays, &rp).unwrap();
            fit_rigid_motion(&corr, &cam, &rp).unwrap()
        })
    });
    let fit = fit_rigid_motion(&corr, &cam, &rp).unwrap();
    g.bench_function("rigidity_residual", |b| {
        b.iter(|| dense_residual(depth, d2, &f02, &rays, &fit.motion, &rp).unwrap())
    });
    // With shared pairs, what the later frame adds: the flow turned around.
    g.bench_function("rigidity_reverse_flow", |b| {
        b.iter(|| reverse_flow(&f02, depth, &rays, &fit.motion, &rp).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
