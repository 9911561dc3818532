//! `--rerun` / `--rerun-save FILE.rrd`: watch a run in the Rerun viewer (`dynapix-rerun`).
//! Built only with the cargo feature `viz` (`cargo build --release -p dynapix-cli --features
//! viz`); without it the flags are still listed and say how to get them.

use std::path::PathBuf;
use std::sync::Arc;

use dynapix::RunObserver;

/// The viewer flags of `run`, `slam` and `bench`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct VizArgs {
    /// Show the run live in the Rerun viewer: connects to a viewer listening on 127.0.0.1:9876
    /// or starts `rerun` (`pip install rerun-sdk==0.36.*`; run `rerun analytics disable` once).
    /// Needs a build with `--features viz`.
    #[arg(long)]
    pub rerun: bool,
    /// Write the run as a Rerun recording (open it with `rerun FILE.rrd`). Needs a build with
    /// `--features viz`.
    #[arg(long, value_name = "FILE.rrd", conflicts_with = "rerun")]
    pub rerun_save: Option<PathBuf>,
    /// Log the colour image, P and depth of every K-th frame only (1: every frame). Poses,
    /// trajectories, keypoints, map and scalars are logged for every frame regardless.
    #[arg(long, value_name = "K", default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..))]
    pub rerun_images_every: u32,
    /// Log the images in every pass of an offline DynaPix run, not only in the last one (the
    /// run's result; the earlier passes make the motion maps). Costs about one more
    /// image-logging pass per extra pass.
    #[arg(long)]
    pub rerun_images_all_passes: bool,
}

/// A run's viewer, when one was asked for.
#[cfg_attr(not(feature = "viz"), allow(dead_code))]
pub struct Viz {
    #[cfg(feature = "viz")]
    observer: Arc<dynapix_rerun::RerunObserver>,
    #[cfg(not(feature = "viz"))]
    observer: Arc<dyn RunObserver>,
}

impl VizArgs {
    /// The viewer asked for (named `name`, e.g. the sequence folder), or `None`.
    pub fn open(&self, name: &str) -> anyhow::Result<Option<Viz>> {
        if !self.rerun && self.rerun_save.is_none() {
            return Ok(None);
        }
        open(self, name).map(Some)
    }
}

#[cfg(feature = "viz")]
fn open(args: &VizArgs, name: &str) -> anyhow::Result<Viz> {
    use dynapix_rerun::{RerunObserver, RerunParams, Target};
    let target = match &args.rerun_save {
        Some(path) => {
            let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
            if let Some(dir) = dir {
                dynapix::OutputFolder::check_writable(dir).map_err(|e| {
                    anyhow::anyhow!("cannot write {}: {}", path.display(), e.reason())
                })?;
            }
            Target::Save(path.clone())
        }
        None => Target::Spawn,
    };
    let params = RerunParams {
        images_every: args.rerun_images_every as usize,
        images_in_all_passes: args.rerun_images_all_passes,
        ..RerunParams::default()
    };
    let observer = RerunObserver::open(&target, name, params)?;
    Ok(Viz {
        observer: Arc::new(observer),
    })
}

#[cfg(not(feature = "viz"))]
fn open(args: &VizArgs, _name: &str) -> anyhow::Result<Viz> {
    let flag = if args.rerun {
        "--rerun"
    } else {
        "--rerun-save"
    };
    anyhow::bail!(
        "{flag} needs the Rerun viewer support, which this build does not have: build with \
         `cargo build --release -p dynapix-cli --features viz`"
    )
}

impl Viz {
    /// The observer to hand to the run.
    pub fn observer(&self) -> Arc<dyn RunObserver> {
        self.observer.clone()
    }

    /// Sends what is left to the viewer or file (a saved recording is complete after this).
    pub fn finish(self) -> anyhow::Result<()> {
        #[cfg(feature = "viz")]
        {
            self.observer.finish()?;
            eprintln!("rerun: recording sent to {}", self.observer.target());
        }
        Ok(())
    }
}
