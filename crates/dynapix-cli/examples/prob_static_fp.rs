//! Diagnostic (loopdyn investigation, `docs/bench/loopdyn.md`): how much motion probability
//! do the maps put on pixels that the ground-truth masks call static, and where (image border,
//! depth edges, textured pixels where ORB finds keypoints), against time and camera rotation
//! speed.
//!
//! ```sh
//! cargo run --release -p dynapix-cli --example prob_static_fp -- SEQ_DIR PROB_DIR [--csv OUT.csv]
//! ```
//! `SEQ_DIR` needs `association.txt`, `mask/` (0 = static), `depth/` and `groundtruth.txt`
//! (one pose per frame, as `dynapix synth` writes); `PROB_DIR` holds the 16-bit maps
//! (value = (1 − P)·1000) named like the rgb images.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, bail};
use dynapix_io::images::{read_depth_raw, read_mask, read_motion_probability, read_rgb};
use nalgebra::UnitQuaternion;

/// Index of the moving pixels in the accumulators.
const MOV: usize = 6;
/// Width (px) of the band along the image border.
const BORDER: u32 = 12;
/// Depth jump (m) to a pixel ≤ 2 px away that marks a depth edge.
const DEPTH_JUMP: f32 = 0.10;
/// Grey-level gradient (central difference) above which a pixel counts as textured.
const TEXTURE: i32 = 24;
/// γ_add of the paper (birth gate).
const GAMMA_ADD: f32 = 0.05;

#[derive(Default, Clone, Copy)]
struct Acc {
    n: u64,
    sum: f64,
    gt05: u64,
    gt10: u64,
}

impl Acc {
    fn add(&mut self, p: f32) {
        self.n += 1;
        self.sum += p as f64;
        self.gt05 += (p > 0.05) as u64;
        self.gt10 += (p > 0.10) as u64;
    }
    fn merge(&mut self, o: &Acc) {
        self.n += o.n;
        self.sum += o.sum;
        self.gt05 += o.gt05;
        self.gt10 += o.gt10;
    }
    fn fmt(&self) -> String {
        if self.n == 0 {
            return "      -       -       -   (n=0)".into();
        }
        let n = self.n as f64;
        format!(
            "{:7.4} {:7.4} {:7.4}   (n={})",
            self.sum / n,
            self.gt05 as f64 / n,
            self.gt10 as f64 / n,
            self.n
        )
    }
}

/// Regions of a static pixel.
const REGIONS: [&str; 6] = [
    "static all",
    "static border",
    "static depth edge",
    "static textured",
    "static interior",
    "static ≤8 px of mover",
];
/// Distance (px, Chebyshev) to a moving pixel within which a static pixel counts as "near".
const NEAR: i32 = 8;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        bail!("usage: prob_static_fp SEQ_DIR PROB_DIR [--csv OUT.csv]");
    }
    let seq = PathBuf::from(&args[0]);
    let prob_dir = PathBuf::from(&args[1]);
    let csv_out = args
        .iter()
        .position(|a| a == "--csv")
        .and_then(|i| args.get(i + 1))
        .map(PathBuf::from);
    let assoc = dynapix_io::tum::read_associations(seq.join("association.txt"))?;
    let gt =
        dynapix_io::Trajectory::read_tum(seq.join("groundtruth.txt")).context("groundtruth.txt")?;
    let rot: Vec<UnitQuaternion<f64>> = gt.poses.iter().map(|p| p.pose.rotation).collect();

    let orb = dynapix_slam::orb::OrbExtractor::default();
    // Keypoints: [static total, static P > γ_add, moving total, moving P > γ_add].
    let mut kp_counts = [0u64; 4];
    let mut total = [Acc::default(); 7];
    let mut per_sec: Vec<[Acc; 7]> = Vec::new();
    let mut csv = String::from(
        "t,rot_deg_per_s,mean_p_static,share_p05_static,share_p10_static,mean_p_border,mean_p_depth_edge,mean_p_textured,mean_p_interior,mean_p_moving,moving_share\n",
    );
    for (i, a) in assoc.iter().enumerate() {
        let stem = std::path::Path::new(&a.rgb)
            .file_stem()
            .context("rgb name")?
            .to_string_lossy()
            .into_owned();
        let prob = read_motion_probability(prob_dir.join(format!("{stem}.png")))?.into_image();
        let mask = read_mask(seq.join("mask").join(format!("{stem}.png")))?;
        let depth = read_depth_raw(seq.join(&a.depth))?;
        let rgb = read_rgb(seq.join(&a.rgb))?;
        let (w, h) = prob.dimensions();
        let gray: Vec<i32> = rgb
            .pixels()
            .map(|p| (p.0[0] as i32 * 299 + p.0[1] as i32 * 587 + p.0[2] as i32 * 114) / 1000)
            .collect();
        let z = |x: u32, y: u32| depth.get_pixel(x, y).0[0] as f32 / 5000.0;
        let (kps, _) = orb.extract(&dynapix_slam::orb::rgb_to_gray_orbslam(&rgb));
        for kp in &kps {
            let (x, y) = (kp.x.round() as u32, kp.y.round() as u32);
            if x >= w || y >= h {
                continue;
            }
            let p = prob.get_pixel(x, y).0[0];
            let k = if mask.get_pixel(x, y).0[0] != 0 { 2 } else { 0 };
            kp_counts[k] += 1;
            kp_counts[k + 1] += (p > GAMMA_ADD) as u64;
        }
        let near = {
            let mut rows = vec![false; (w * h) as usize];
            for y in 0..h as i32 {
                for x in 0..w as i32 {
                    let lo = (x - NEAR).max(0);
                    let hi = (x + NEAR).min(w as i32 - 1);
                    rows[(y as u32 * w + x as u32) as usize] =
                        (lo..=hi).any(|xx| mask.get_pixel(xx as u32, y as u32).0[0] != 0);
                }
            }
            let mut out = vec![false; (w * h) as usize];
            for y in 0..h as i32 {
                for x in 0..w as i32 {
                    let lo = (y - NEAR).max(0);
                    let hi = (y + NEAR).min(h as i32 - 1);
                    out[(y as u32 * w + x as u32) as usize] =
                        (lo..=hi).any(|yy| rows[(yy as u32 * w + x as u32) as usize]);
                }
            }
            out
        };
        let mut acc = [Acc::default(); 7];
        for y in 0..h {
            for x in 0..w {
                let p = prob.get_pixel(x, y).0[0];
                if mask.get_pixel(x, y).0[0] != 0 {
                    acc[MOV].add(p);
                    continue;
                }
                acc[0].add(p);
                let border = x < BORDER || y < BORDER || x >= w - BORDER || y >= h - BORDER;
                let zc = z(x, y);
                let mut edge = zc == 0.0;
                'n: for dy in -2i32..=2 {
                    for dx in -2i32..=2 {
                        let (xx, yy) = (x as i32 + dx, y as i32 + dy);
                        if xx >= 0 && yy >= 0 && (xx as u32) < w && (yy as u32) < h {
                            let zn = z(xx as u32, yy as u32);
                            if zn == 0.0 || (zn - zc).abs() > DEPTH_JUMP {
                                edge = true;
                                break 'n;
                            }
                        }
                    }
                }
                let textured = x > 0 && y > 0 && x + 1 < w && y + 1 < h && {
                    let g = |xx: u32, yy: u32| gray[(yy * w + xx) as usize];
                    let gx = g(x + 1, y) - g(x - 1, y);
                    let gy = g(x, y + 1) - g(x, y - 1);
                    gx.abs().max(gy.abs()) > TEXTURE
                };
                if border {
                    acc[1].add(p);
                } else if edge {
                    acc[2].add(p);
                } else {
                    acc[4].add(p);
                }
                if textured && !border && !edge {
                    acc[3].add(p);
                }
                if near[(y * w + x) as usize] {
                    acc[5].add(p);
                }
            }
        }
        let t = a.t_rgb;
        let speed = if i > 0 && i < rot.len() {
            rot[i - 1].angle_to(&rot[i]).to_degrees() / (t - assoc[i - 1].t_rgb)
        } else {
            0.0
        };
        let m = |a: &Acc| {
            if a.n > 0 {
                a.sum / a.n as f64
            } else {
                f64::NAN
            }
        };
        let s = |c: u64, a: &Acc| {
            if a.n > 0 {
                c as f64 / a.n as f64
            } else {
                f64::NAN
            }
        };
        writeln!(
            csv,
            "{t:.3},{speed:.1},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
            m(&acc[0]),
            s(acc[0].gt05, &acc[0]),
            s(acc[0].gt10, &acc[0]),
            m(&acc[1]),
            m(&acc[2]),
            m(&acc[3]),
            m(&acc[4]),
            m(&acc[MOV]),
            acc[MOV].n as f64 / (w * h) as f64
        )?;
        let sec = t.floor() as usize;
        if per_sec.len() <= sec {
            per_sec.resize(sec + 1, [Acc::default(); 7]);
        }
        for k in 0..7 {
            total[k].merge(&acc[k]);
            per_sec[sec][k].merge(&acc[k]);
        }
    }
    println!("region               mean P  P>0.05  P>0.10");
    for (k, name) in REGIONS.iter().enumerate() {
        println!("{name:<20} {}", total[k].fmt());
    }
    println!("{:<20} {}", "moving (mask)", total[MOV].fmt());
    println!(
        "ORB keypoints (1000/frame): static {} of which P > γ_add {}; moving {} of which P > γ_add {}",
        kp_counts[0], kp_counts[1], kp_counts[2], kp_counts[3]
    );
    println!(
        "\nper second (static pixels): t  mean P  P>0.05  P>0.10 | border | depth edge | textured | moving"
    );
    for (s, a) in per_sec.iter().enumerate() {
        let m = |a: &Acc| {
            if a.n > 0 {
                a.sum / a.n as f64
            } else {
                f64::NAN
            }
        };
        println!(
            "{s:2} {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4}",
            a[0].fmt(),
            m(&a[1]),
            m(&a[2]),
            m(&a[3]),
            m(&a[5]),
            m(&a[MOV])
        );
    }
    if let Some(p) = csv_out {
        std::fs::write(&p, csv).with_context(|| format!("cannot write {}", p.display()))?;
    }
    Ok(())
}
