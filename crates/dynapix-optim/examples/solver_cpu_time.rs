//! CPU time per solver call on the benchmark problems, measured from `/proc/self/stat`
//! (user + system time of the whole process), so that a loaded machine inflates the figures
//! less than wall-clock timings. Run single-threaded for per-core cost:
//! `RAYON_NUM_THREADS=1 cargo run --release -p dynapix-optim --example solver_cpu_time`.

#[path = "../benches/common/mod.rs"]
mod common;

use dynapix_geometry::PinholeCamera;
use dynapix_geometry::pnp::{PnpRansac, PnpRansacParams};
use dynapix_optim::{
    BaParams, PoseGraphParams, PoseOnlyParams, bundle_adjust, optimize_pose, optimize_pose_graph,
};
use std::hint::black_box;
use std::time::Instant;

/// Process CPU time in seconds (Linux only; 0 elsewhere).
fn cpu_seconds() -> f64 {
    dynapix_io::usage::cpu_seconds().unwrap_or(0.0)
}

fn measure(name: &str, calls: usize, mut f: impl FnMut()) {
    f();
    let (c0, w0) = (cpu_seconds(), Instant::now());
    for _ in 0..calls {
        f();
    }
    let cpu = (cpu_seconds() - c0) / calls as f64 * 1e3;
    let wall = w0.elapsed().as_secs_f64() / calls as f64 * 1e3;
    println!("{name}: {cpu:.3} ms CPU, {wall:.3} ms wall per call ({calls} calls)");
}

fn main() {
    let p = common::pose_problem();
    let pp = PoseOnlyParams::default();
    measure("pose_only_300_edges", 2000, || {
        black_box(optimize_pose(black_box(&p), &pp));
    });
    let ba = common::ba_problem();
    let bp = BaParams::default();
    measure("local_ba_10_poses_2000_points_10000_edges", 60, || {
        black_box(bundle_adjust(black_box(&ba), &bp));
    });
    let (poses, fixed, edges) = common::pose_graph_problem();
    let pg = PoseGraphParams::default();
    measure("pose_graph_200_poses_399_edges", 20, || {
        black_box(optimize_pose_graph(black_box(&poses), &fixed, &edges, &pg));
    });
    let (pw, px, s2) = common::pnp_problem();
    let cam = PinholeCamera::new(640, 480, 535.4, 539.2, 320.1, 247.6);
    let rp = PnpRansacParams::default();
    measure("epnp_ransac_150_points_30pct_outliers", 2000, || {
        let r = PnpRansac::new(black_box(&pw), black_box(&px), &s2, &cam, &rp)
            .ok()
            .and_then(|mut r| r.solve());
        black_box(r);
    });
}
