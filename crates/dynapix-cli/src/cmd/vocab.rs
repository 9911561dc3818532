//! `dynapix vocab`: train a bag-of-words vocabulary on ORB features of a set of images, or
//! convert ORB-SLAM2's `ORBvoc.txt` to the compact dynapix binary format (spec §6.9).

use anyhow::{Context, bail};
use dynapix_slam::orb::{OrbExtractor, OrbParams, rgb_to_gray_orbslam};
use dynapix_slam::vocab::{TrainParams, Vocabulary};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `dynapix vocab`.
#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: VocabCommand,
}

#[derive(clap::Subcommand)]
enum VocabCommand {
    /// Train a vocabulary on the ORB descriptors of images (PNG/JPEG files, folders of them, or
    /// `*`/`?` patterns in the file name).
    Train(TrainArgs),
    /// Convert an ORB-SLAM2 / DBoW2 text vocabulary (`ORBvoc.txt`, uncompressed) to the binary
    /// format.
    Import(ImportArgs),
}

#[derive(clap::Args)]
struct TrainArgs {
    /// Images, folders (their *.png / *.jpg files, sorted) or file-name patterns.
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Output vocabulary file (dynapix binary format).
    #[arg(long)]
    out: PathBuf,
    /// Branching factor.
    #[arg(long, default_value_t = 10)]
    k: usize,
    /// Depth of the tree; about descriptors/10 ≈ k^levels is a good size.
    #[arg(long, default_value_t = 4)]
    levels: usize,
    /// Use at most this many images, evenly spaced over the sorted list.
    #[arg(long)]
    max_images: Option<usize>,
    /// ORB features per image.
    #[arg(long, default_value_t = 1000)]
    nfeatures: usize,
    /// Seed of the k-means++ initialisation.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(clap::Args)]
struct ImportArgs {
    /// The ORB-SLAM2 text vocabulary.
    input: PathBuf,
    /// Output vocabulary file (dynapix binary format).
    #[arg(long)]
    out: PathBuf,
}

/// Runs `dynapix vocab`.
pub fn run(args: Args, bars: &super::common::Bars) -> anyhow::Result<()> {
    match args.command {
        VocabCommand::Train(a) => train(a, bars),
        VocabCommand::Import(a) => import(a),
    }
}

fn is_image(p: &Path) -> bool {
    matches!(
        p.extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .as_deref(),
        Some("png" | "jpg" | "jpeg")
    )
}

/// `*` and `?` wildcard match of a file name.
fn wildcard(pattern: &[u8], name: &[u8]) -> bool {
    match (pattern.first(), name.first()) {
        (None, None) => true,
        (Some(b'*'), _) => {
            wildcard(&pattern[1..], name) || (!name.is_empty() && wildcard(pattern, &name[1..]))
        }
        (Some(b'?'), Some(_)) => wildcard(&pattern[1..], &name[1..]),
        (Some(a), Some(b)) if a == b => wildcard(&pattern[1..], &name[1..]),
        _ => false,
    }
}

/// Expands files, folders and file-name patterns into a sorted, de-duplicated image list.
fn collect_images(inputs: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let list_dir = |dir: &Path| -> anyhow::Result<Vec<PathBuf>> {
        let rd = std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))?;
        let mut v = Vec::new();
        for e in rd {
            let e = e.with_context(|| format!("reading {}", dir.display()))?;
            v.push(e.path());
        }
        Ok(v)
    };
    for input in inputs {
        let name = input
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.contains(['*', '?']) {
            let dir = match input.parent() {
                Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
                _ => PathBuf::from("."),
            };
            let mut hits: Vec<PathBuf> = list_dir(&dir)?
                .into_iter()
                .filter(|p| {
                    p.file_name()
                        .map(|n| wildcard(name.as_bytes(), n.to_string_lossy().as_bytes()))
                        .unwrap_or(false)
                        && p.is_file()
                })
                .collect();
            if hits.is_empty() {
                bail!("pattern {} matches no file", input.display());
            }
            out.append(&mut hits);
        } else if input.is_dir() {
            let mut hits: Vec<PathBuf> = list_dir(input)?
                .into_iter()
                .filter(|p| p.is_file() && is_image(p))
                .collect();
            if hits.is_empty() {
                bail!("folder {} holds no PNG/JPEG images", input.display());
            }
            out.append(&mut hits);
        } else if input.is_file() {
            out.push(input.clone());
        } else {
            bail!("{} is not a file, folder or pattern", input.display());
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}

/// Evenly spaced subset of `n` items (all when `n` ≥ len).
fn subsample<T: Clone>(items: &[T], n: Option<usize>) -> Vec<T> {
    match n {
        Some(n) if n < items.len() && n > 0 => {
            (0..n).map(|i| items[i * items.len() / n].clone()).collect()
        }
        _ => items.to_vec(),
    }
}

fn train(a: TrainArgs, bars: &super::common::Bars) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let all = collect_images(&a.images)?;
    let images = subsample(&all, a.max_images);
    if images.is_empty() {
        bail!("no images to train on");
    }
    let orb = OrbExtractor::new(OrbParams {
        nfeatures: a.nfeatures,
        ..OrbParams::default()
    })?;
    let bar = bars.adopt(
        ProgressBar::new(images.len() as u64).with_style(
            ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} {per_sec} eta {eta}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        ),
    );
    bar.set_message("ORB features");
    let descs: Vec<Vec<[u8; 32]>> = images
        .par_iter()
        .map(|p| -> anyhow::Result<Vec<[u8; 32]>> {
            let img = dynapix_io::images::read_rgb(p)?;
            let gray = rgb_to_gray_orbslam(&img);
            let (_, d) = orb.extract(&gray);
            bar.inc(1);
            Ok(d)
        })
        .collect::<anyhow::Result<_>>()?;
    bar.finish_and_clear();
    let n_desc: usize = descs.iter().map(|d| d.len()).sum();
    tracing::info!(
        images = images.len(),
        descriptors = n_desc,
        "features extracted in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    let spinner = bars.adopt(ProgressBar::new_spinner());
    spinner.set_message(format!(
        "training k={} L={} on {n_desc} descriptors",
        a.k, a.levels
    ));
    spinner.enable_steady_tick(std::time::Duration::from_millis(200));
    let t1 = Instant::now();
    let params = TrainParams {
        k: a.k,
        levels: a.levels,
        seed: a.seed,
        ..TrainParams::default()
    };
    let voc = Vocabulary::train(&descs, &params)?;
    spinner.finish_and_clear();
    voc.save(&a.out)?;
    let size = std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0);
    eprintln!(
        "trained on {} images, {n_desc} descriptors: {} nodes, {} words (k={}, L={}) in {:.1} s; wrote {} ({} bytes)",
        images.len(),
        voc.node_count(),
        voc.word_count(),
        a.k,
        a.levels,
        t1.elapsed().as_secs_f64(),
        a.out.display(),
        size
    );
    Ok(())
}

fn import(a: ImportArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let voc =
        Vocabulary::load(&a.input).with_context(|| format!("importing {}", a.input.display()))?;
    voc.save(&a.out)?;
    eprintln!(
        "imported {}: {} nodes, {} words (k={}, L={}) in {:.1} s; wrote {}",
        a.input.display(),
        voc.node_count(),
        voc.word_count(),
        voc.branching(),
        voc.levels(),
        t0.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wildcards() {
        assert!(wildcard(b"*.png", b"a.png"));
        assert!(wildcard(b"1305*.png", b"1305031102.175304.png"));
        assert!(!wildcard(b"*.png", b"a.jpg"));
        assert!(wildcard(b"a?c", b"abc"));
        assert!(!wildcard(b"a?c", b"ac"));
    }

    #[test]
    fn subsampling_is_even() {
        let v: Vec<usize> = (0..10).collect();
        assert_eq!(subsample(&v, Some(5)), vec![0, 2, 4, 6, 8]);
        assert_eq!(subsample(&v, Some(20)).len(), 10);
        assert_eq!(subsample(&v, None).len(), 10);
    }
}
