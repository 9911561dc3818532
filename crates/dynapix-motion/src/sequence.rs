//! Motion maps of a whole sequence: the per-frame algorithms of this crate
//! ([`motion_probability`], [`reconstruct_background`]) run over every requested frame with
//! the neighbours and backgrounds each one needs (paper §3.1, offline schedule: neighbours on
//! both sides, backgrounds from past and future frames).
//!
//! Frames come from a [`FrameLoader`] (files, memory, a camera buffer), so this module does no
//! I/O itself. Work goes in chunks of frames: the images and backgrounds a chunk needs are
//! loaded or reconstructed once (in parallel), kept while the next chunk still needs them, and
//! the frames of the chunk are computed in parallel. Every result is handed to a per-frame
//! `map` closure (in parallel, e.g. to write a file) whose outputs are then passed to `fold`
//! in frame order, so progress and accumulated statistics are deterministic.

use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;
use std::time::Instant;

use dynapix_flow::FlowProvider;
use dynapix_geometry::{PinholeCamera, Se3};
use image::RgbImage;
use rayon::prelude::*;

use crate::background::{ReconstructParams, Source, reconstruct_background};
use crate::moving::{FrameImages, Neighbour};
use crate::pipeline::{MotionMaps, MotionParams, motion_probability};
use crate::{FloatImage, MotionError};

/// Error of a frame loader or of a per-frame consumer.
pub type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// The colour image and depth (metres, 0 = invalid) of one frame.
#[derive(Clone, Debug)]
pub struct RgbdImages {
    /// Colour image.
    pub rgb: RgbImage,
    /// Depth in metres.
    pub depth: FloatImage,
}

/// A static background (colour and depth) for one frame.
#[derive(Clone, Debug)]
pub struct StaticBackground {
    /// Background colour image.
    pub rgb: RgbImage,
    /// Background depth in metres (the dynamic depth when no other is known, as the reference
    /// does on TUM).
    pub depth: FloatImage,
}

/// Where the frames of a sequence come from.
pub trait FrameLoader: Sync {
    /// Number of frames.
    fn len(&self) -> usize;
    /// True when there is no frame.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// False for a frame that is not to be used (e.g. its files are known to be broken): it
    /// is never loaded, and its neighbours do without it as if it lay beyond the sequence.
    fn available(&self, i: usize) -> bool {
        let _ = i;
        true
    }
    /// The images of frame `i`.
    fn frame(&self, i: usize) -> Result<RgbdImages, BoxError>;
    /// The given static background of frame `i` (a rendered or inpainted `background/`
    /// folder); only called with [`Backgrounds::Given`]. `frame` is frame `i`'s images, for a
    /// loader that has no background depth and uses the frame's.
    fn background(&self, i: usize, frame: &RgbdImages) -> Result<StaticBackground, BoxError>;
}

/// How every frame gets its static background.
#[derive(Clone, Debug, PartialEq)]
pub enum Backgrounds {
    /// From the loader ([`FrameLoader::background`]).
    Given,
    /// Reconstructed from neighbouring frames ([`reconstruct_background`]).
    Reconstruct(ReconstructParams),
}

impl Backgrounds {
    /// True for [`Backgrounds::Reconstruct`].
    pub fn reconstructs(&self) -> bool {
        matches!(self, Backgrounds::Reconstruct(_))
    }
}

/// Errors of [`SequenceMotion::run`], each naming the frame.
#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    /// The loader failed.
    #[error("frame {index}: {source}")]
    Load {
        /// Frame index.
        index: usize,
        /// What went wrong.
        source: BoxError,
    },
    /// The background reconstruction failed.
    #[error("frame {index}: background: {source}")]
    Background {
        /// Frame index.
        index: usize,
        /// What went wrong.
        source: MotionError,
    },
    /// The motion probability failed.
    #[error("frame {index}: {source}")]
    Motion {
        /// Frame index.
        index: usize,
        /// What went wrong.
        source: MotionError,
    },
    /// The per-frame consumer failed.
    #[error("frame {index}: {source}")]
    Consumer {
        /// Frame index.
        index: usize,
        /// What went wrong.
        source: BoxError,
    },
    /// The input does not fit together.
    #[error("{0}")]
    Input(String),
}

/// What the per-frame consumer gets.
#[derive(Debug)]
pub struct FrameMotion<'a> {
    /// Frame index.
    pub index: usize,
    /// P, D and M of the frame.
    pub maps: MotionMaps,
    /// The frame's images.
    pub images: &'a RgbdImages,
    /// The static background used for the frame.
    pub background: &'a StaticBackground,
}

/// Counters of one [`SequenceMotion::run`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SequenceStats {
    /// Frames computed.
    pub frames: usize,
    /// Wall-clock seconds spent in the motion and background computation (without loading).
    pub compute_seconds: f64,
}

/// The motion-map computation of a sequence: inputs shared by every frame.
pub struct SequenceMotion<'a> {
    /// The frames.
    pub loader: &'a dyn FrameLoader,
    /// Camera-to-world pose `T_wc` of every frame (only read when
    /// [`SequenceMotion::needs_poses`]).
    pub poses: &'a [Se3],
    /// The camera (its size is the size of every image).
    pub camera: &'a PinholeCamera,
    /// Optical flow.
    pub flow: &'a dyn FlowProvider,
    /// Motion-probability parameters.
    pub params: &'a MotionParams,
    /// Background source.
    pub backgrounds: &'a Backgrounds,
}

impl SequenceMotion<'_> {
    /// True when the computation uses poses: the moving term splats neighbours, and a
    /// reconstructed background splats neighbouring frames.
    pub fn needs_poses(params: &MotionParams, backgrounds: &Backgrounds) -> bool {
        params.use_moving || backgrounds.reconstructs()
    }

    /// Frames per chunk: enough parallel work for every thread, few enough frames in memory.
    fn chunk_len() -> usize {
        2 * rayon::current_num_threads().max(1) * 4
    }

    /// Computes the maps of `frames` (indices into the loader, any order; each is computed
    /// once in the given order of chunks). `map` receives every frame's result, in parallel,
    /// and its output goes to `fold` in the order of `frames`.
    pub fn run<R, F, G>(
        &self,
        frames: &[usize],
        map: F,
        mut fold: G,
    ) -> Result<SequenceStats, SequenceError>
    where
        R: Send,
        F: Fn(FrameMotion<'_>) -> Result<R, BoxError> + Sync,
        G: FnMut(usize, R),
    {
        let n = self.loader.len();
        if let Some(&bad) = frames.iter().find(|&&i| i >= n) {
            return Err(SequenceError::Input(format!(
                "frame {bad} requested, the sequence has {n}"
            )));
        }
        if Self::needs_poses(self.params, self.backgrounds) && self.poses.len() != n {
            return Err(SequenceError::Input(format!(
                "{} poses for {n} frames",
                self.poses.len()
            )));
        }
        let in_range = |j: i64| {
            (j >= 0 && (j as usize) < n && self.loader.available(j as usize)).then_some(j as usize)
        };
        if let Some(&bad) = frames.iter().find(|&&i| !self.loader.available(i)) {
            return Err(SequenceError::Input(format!(
                "frame {bad} requested, but the loader marks it unavailable"
            )));
        }
        let moving_offsets: Vec<i64> = if self.params.use_moving {
            self.params.offsets.clone()
        } else {
            Vec::new()
        };
        let bg_offsets = match self.backgrounds {
            Backgrounds::Reconstruct(r) => r.offsets(),
            Backgrounds::Given => Vec::new(),
        };
        let mut frame_cache: HashMap<usize, Arc<RgbdImages>> = HashMap::new();
        let mut bg_cache: HashMap<usize, Arc<StaticBackground>> = HashMap::new();
        let mut stats = SequenceStats::default();
        for chunk in frames.chunks(Self::chunk_len()) {
            // Frames whose images and backgrounds this chunk needs.
            let mut need_bg = BTreeSet::new();
            for &i in chunk {
                need_bg.insert(i);
                for &o in &moving_offsets {
                    if let Some(j) = in_range(i as i64 + o) {
                        need_bg.insert(j);
                    }
                }
            }
            let mut need_frames = need_bg.clone();
            for &b in &need_bg {
                for &o in &bg_offsets {
                    if let Some(j) = in_range(b as i64 + o) {
                        need_frames.insert(j);
                    }
                }
            }
            frame_cache.retain(|k, _| need_frames.contains(k));
            bg_cache.retain(|k, _| need_bg.contains(k));
            let missing: Vec<usize> = need_frames
                .iter()
                .copied()
                .filter(|k| !frame_cache.contains_key(k))
                .collect();
            let loaded = missing
                .par_iter()
                .map(|&i| {
                    self.loader
                        .frame(i)
                        .map(|l| (i, Arc::new(l)))
                        .map_err(|source| SequenceError::Load { index: i, source })
                })
                .collect::<Result<Vec<_>, _>>()?;
            frame_cache.extend(loaded);
            let missing_bg: Vec<usize> = need_bg
                .iter()
                .copied()
                .filter(|k| !bg_cache.contains_key(k))
                .collect();
            let t0 = Instant::now();
            let bgs = missing_bg
                .par_iter()
                .map(|&i| {
                    self.background(i, &frame_cache, &bg_offsets)
                        .map(|b| (i, Arc::new(b)))
                })
                .collect::<Result<Vec<_>, _>>()?;
            bg_cache.extend(bgs);
            stats.compute_seconds += t0.elapsed().as_secs_f64();

            let t0 = Instant::now();
            let results = chunk
                .par_iter()
                .map(|&i| -> Result<R, SequenceError> {
                    let view = |k: usize| FrameImages {
                        rgb: &frame_cache[&k].rgb,
                        depth: &frame_cache[&k].depth,
                        background: &bg_cache[&k].rgb,
                        background_depth: &bg_cache[&k].depth,
                    };
                    let t_cw = self.pose(i).inverse();
                    let nbs: Vec<Neighbour> = moving_offsets
                        .iter()
                        .filter_map(|&o| in_range(i as i64 + o))
                        .map(|j| Neighbour {
                            frame: view(j),
                            t_cn: t_cw * self.pose(j),
                        })
                        .collect();
                    let maps =
                        motion_probability(&view(i), &nbs, self.camera, self.flow, self.params)
                            .map_err(|source| SequenceError::Motion { index: i, source })?;
                    map(FrameMotion {
                        index: i,
                        maps,
                        images: &frame_cache[&i],
                        background: &bg_cache[&i],
                    })
                    .map_err(|source| SequenceError::Consumer { index: i, source })
                })
                .collect::<Result<Vec<_>, _>>()?;
            stats.compute_seconds += t0.elapsed().as_secs_f64();
            for (&i, r) in chunk.iter().zip(results) {
                stats.frames += 1;
                fold(i, r);
            }
        }
        Ok(stats)
    }

    /// Pose of frame `i` (identity when poses are not needed and not given).
    fn pose(&self, i: usize) -> Se3 {
        self.poses.get(i).copied().unwrap_or_else(Se3::identity)
    }

    /// The background of frame `i` from the loaded frames.
    fn background(
        &self,
        i: usize,
        frames: &HashMap<usize, Arc<RgbdImages>>,
        offsets: &[i64],
    ) -> Result<StaticBackground, SequenceError> {
        let cur = &frames[&i];
        match self.backgrounds {
            Backgrounds::Given => self
                .loader
                .background(i, cur)
                .map_err(|source| SequenceError::Load { index: i, source }),
            Backgrounds::Reconstruct(params) => {
                let n = self.loader.len() as i64;
                let t_cw = self.pose(i).inverse();
                let sources: Vec<Source> = offsets
                    .iter()
                    .map(|&o| i as i64 + o)
                    .filter(|&j| (0..n).contains(&j) && self.loader.available(j as usize))
                    .map(|j| {
                        let j = j as usize;
                        Source {
                            rgb: &frames[&j].rgb,
                            depth: &frames[&j].depth,
                            t_ts: t_cw * self.pose(j),
                        }
                    })
                    .collect();
                let _stage =
                    tracing::info_span!(target: "dynapix::stage", "paper: background").entered();
                let b = reconstruct_background(
                    &cur.rgb,
                    &cur.depth,
                    &sources,
                    self.camera,
                    params,
                    Some(self.flow),
                )
                .map_err(|source| SequenceError::Background { index: i, source })?;
                Ok(StaticBackground {
                    rgb: b.image,
                    depth: b.depth,
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{BlockFlow, Scene, small_camera};
    use crate::{Mode, Variant};
    use std::sync::Mutex;

    /// Five frames of the test scene with a mover, camera sliding along x.
    struct Frames {
        cam: PinholeCamera,
        poses: Vec<Se3>,
        loads: Mutex<usize>,
    }

    impl FrameLoader for Frames {
        fn len(&self) -> usize {
            self.poses.len()
        }
        fn frame(&self, i: usize) -> Result<RgbdImages, BoxError> {
            *self.loads.lock().unwrap() += 1;
            let (rgb, depth) =
                Scene::default().render(&self.cam, &self.poses[i], true, -0.25 + 0.08 * i as f64);
            Ok(RgbdImages { rgb, depth })
        }
        fn background(&self, i: usize, _: &RgbdImages) -> Result<StaticBackground, BoxError> {
            if i == 99 {
                return Err("no such background".into());
            }
            let (rgb, depth) = Scene::default().render(&self.cam, &self.poses[i], false, 0.0);
            Ok(StaticBackground { rgb, depth })
        }
    }

    fn frames() -> Frames {
        Frames {
            cam: small_camera(),
            poses: (0..5)
                .map(|i| Se3::translation(0.02 * i as f64, 0.0, 0.0))
                .collect(),
            loads: Mutex::new(0),
        }
    }

    #[test]
    fn sequence_results_equal_the_per_frame_computation_and_fold_in_order() {
        let f = frames();
        let flow = BlockFlow { radius: 5, half: 2 };
        let params = MotionParams::new(Variant::Tum, Mode::Paper);
        let seq = SequenceMotion {
            loader: &f,
            poses: &f.poses,
            camera: &f.cam,
            flow: &flow,
            params: &params,
            backgrounds: &Backgrounds::Given,
        };
        let mut order = Vec::new();
        let mut maps = HashMap::new();
        let stats = seq
            .run(
                &[3, 0, 4, 1, 2],
                |m| Ok(m.maps.p),
                |i, p| {
                    order.push(i);
                    maps.insert(i, p);
                },
            )
            .unwrap();
        assert_eq!(order, vec![3, 0, 4, 1, 2]);
        assert_eq!(stats.frames, 5);
        // Frame 2 by hand: neighbours 1 and 3 with their rendered backgrounds.
        let imgs: Vec<RgbdImages> = (0..5).map(|i| f.frame(i).unwrap()).collect();
        let bgs: Vec<StaticBackground> =
            (0..5).map(|i| f.background(i, &imgs[i]).unwrap()).collect();
        let view = |k: usize| FrameImages {
            rgb: &imgs[k].rgb,
            depth: &imgs[k].depth,
            background: &bgs[k].rgb,
            background_depth: &bgs[k].depth,
        };
        let nbs: Vec<Neighbour> = [1, 3]
            .iter()
            .map(|&j| Neighbour {
                frame: view(j),
                t_cn: f.poses[2].inverse() * f.poses[j],
            })
            .collect();
        let direct = motion_probability(&view(2), &nbs, &f.cam, &flow, &params).unwrap();
        assert_eq!(maps[&2], direct.p);
        // The mover is found.
        assert!(direct.p.iter().any(|&p| p > 0.5));
    }

    /// [`Frames`] with frame 2 unavailable.
    struct WithoutTwo(Frames);

    impl FrameLoader for WithoutTwo {
        fn len(&self) -> usize {
            self.0.len()
        }
        fn available(&self, i: usize) -> bool {
            i != 2
        }
        fn frame(&self, i: usize) -> Result<RgbdImages, BoxError> {
            assert_ne!(i, 2, "an unavailable frame was loaded");
            self.0.frame(i)
        }
        fn background(&self, i: usize, f: &RgbdImages) -> Result<StaticBackground, BoxError> {
            self.0.background(i, f)
        }
    }

    #[test]
    fn unavailable_frames_are_never_loaded_and_their_neighbours_do_without() {
        let f = WithoutTwo(frames());
        let flow = BlockFlow { radius: 5, half: 2 };
        let params = MotionParams::new(Variant::Tum, Mode::Paper);
        for backgrounds in [
            Backgrounds::Given,
            Backgrounds::Reconstruct(ReconstructParams::default()),
        ] {
            let seq = SequenceMotion {
                loader: &f,
                poses: &f.0.poses,
                camera: &f.0.cam,
                flow: &flow,
                params: &params,
                backgrounds: &backgrounds,
            };
            let mut done = Vec::new();
            seq.run(&[0, 1, 3, 4], |m| Ok(m.index), |_, i| done.push(i))
                .unwrap();
            assert_eq!(done, vec![0, 1, 3, 4]);
            let e = seq.run(&[2], |_| Ok(()), |_, _| {}).unwrap_err();
            assert!(matches!(e, SequenceError::Input(_)), "{e}");
        }
    }

    #[test]
    fn errors_name_the_frame_and_bad_input_is_refused() {
        let f = frames();
        let flow = BlockFlow { radius: 5, half: 2 };
        let params = MotionParams::default();
        let seq = SequenceMotion {
            loader: &f,
            poses: &f.poses[..3],
            camera: &f.cam,
            flow: &flow,
            params: &params,
            backgrounds: &Backgrounds::Given,
        };
        let e = seq.run(&[0], |_| Ok(()), |_, _| {}).unwrap_err();
        assert!(e.to_string().contains("3 poses for 5 frames"), "{e}");
        let seq = SequenceMotion {
            poses: &f.poses,
            ..seq
        };
        let e = seq.run(&[7], |_| Ok(()), |_, _| {}).unwrap_err();
        assert!(matches!(e, SequenceError::Input(_)), "{e}");
        let e = seq
            .run(
                &[1],
                |m| Err(format!("disk full at {}", m.index).into()),
                |_, _: ()| {},
            )
            .unwrap_err();
        assert!(
            matches!(e, SequenceError::Consumer { index: 1, .. })
                && e.to_string().contains("disk full at 1"),
            "{e}"
        );
    }
}
