//! The per-frame steps of the online system: motion of a frame from the frames seen so far
//! (and the lookahead), tracking, and the bookkeeping of the window.

use super::*;

impl Core {
    /// The latency in frames.
    pub(super) fn lookahead(&self) -> usize {
        self.config.online.lookahead
    }

    /// `T_cw` predicted for frame `index` by the constant-velocity model.
    pub(super) fn predict_cw(&self, index: usize) -> Se3 {
        match (self.last_tracked.front(), self.last_tracked.back()) {
            (Some(&(ia, a)), Some(&(ib, b))) if ib > ia => {
                // Velocity per frame, applied for the frames since the last tracked one.
                let v = b * a.inverse();
                let per = 1.0 / (ib - ia) as f64;
                let step = dynapix_geometry::se3::exp(&(dynapix_geometry::se3::log(&v) * per));
                let mut t = b;
                for _ in ib..index {
                    t = step * t;
                }
                t
            }
            (_, Some(&(_, b))) => b,
            _ => Se3::identity(),
        }
    }

    /// Background sources of a target frame: the frames waiting in the lookahead (predicted
    /// poses), window frames every `step`, then keyframes.
    pub(super) fn background_sources(&self, index: usize) -> Vec<(&RgbImage, &DepthImage, Se3)> {
        let step = self.recon.step.max(1);
        let mut out = Vec::new();
        for (j, f) in self.pending.iter().take(self.lookahead()) {
            if *j != index {
                out.push((&f.rgb, &f.depth, self.predict_cw(*j).inverse()));
            }
        }
        for p in self.window.iter().rev() {
            let back = index - p.index;
            if back.is_multiple_of(step) && back <= self.recon.radius {
                out.push((&p.images.rgb, &p.images.depth, p.pose_wc));
            }
        }
        let newest_window = self.window.front().map_or(usize::MAX, |p| p.index);
        for k in self.keyframes.iter().rev() {
            if k.index < newest_window {
                out.push((&k.images.rgb, &k.images.depth, k.pose_wc));
            }
        }
        out
    }

    /// The reconstructed background of frame `index` (images `cur`) seen from `t_wc`.
    pub(super) fn background(
        &self,
        index: usize,
        cur: &RgbdImages,
        t_wc: &Se3,
    ) -> Result<StaticBackground> {
        let t_cw = t_wc.inverse();
        let sources: Vec<Source> = self
            .background_sources(index)
            .into_iter()
            .map(|(rgb, depth, pose)| Source {
                rgb,
                depth,
                t_ts: t_cw * pose,
            })
            .collect();
        let b = reconstruct_background(
            &cur.rgb,
            &cur.depth,
            &sources,
            &self.cam,
            &self.recon,
            Some(&self.flow),
        )?;
        Ok(StaticBackground {
            rgb: b.image,
            depth: b.depth,
        })
    }

    /// The motion map of frame `index` (images `images`) as static weights, with what the
    /// window keeps of it.
    /// `early_rigidity`: the frame's rigidity cue computed during the push before
    /// ([`Core::take_ahead`]), used instead of computing it.
    pub(super) fn weights(
        &self,
        index: usize,
        images: &RgbdImages,
        early_rigidity: Option<FloatImage>,
    ) -> Result<FrameMotion> {
        let t0 = Instant::now();
        let t_wc = self.predict_cw(index).inverse();
        let mut background_ms = 0.0;
        let cues = self.cues.unwrap_or(Cues {
            paper: false,
            geometric: false,
            rigidity: false,
        });
        let gray = cues.rigidity.then(|| Arc::new(to_gray(&images.rgb)));
        let working = cues.geometric.then(|| {
            Arc::new(WorkingDepth::new(
                &images.depth,
                &self.config.motion.static_depth,
            ))
        });
        let (weights, background, mean_probability) = match self.cues {
            None => (None, None, 0.0),
            Some(cues) => {
                let mut paper = None;
                let mut background = None;
                if let Some(params) = &self.params {
                    let bg = Arc::new(self.background(index, images, &t_wc)?);
                    background_ms = t0.elapsed().as_secs_f64() * 1e3;
                    paper = Some(self.motion(index, images, &bg, &t_wc, params)?.into_image());
                    background = Some(bg);
                }
                // The two cues are independent: compute them side by side, combine in order.
                let (rigid, geometric) = rayon::join(
                    || match early_rigidity {
                        Some(r) if gray.is_some() => Ok(Some(r)),
                        _ => gray
                            .as_ref()
                            .map(|g| self.rigidity(index, g, &images.depth))
                            .transpose(),
                    },
                    || {
                        working
                            .as_ref()
                            .filter(|_| cues.geometric)
                            .map(|w| self.geometric(index, w, &t_wc))
                            .transpose()
                    },
                );
                let cues = FrameCues {
                    paper,
                    geometric: geometric?,
                    rigidity: rigid?,
                };
                let p = MotionProbability::new(cues.combine(self.cam.width, self.cam.height)?);
                let mean = p.as_image().iter().sum::<f32>() / p.as_image().len().max(1) as f32;
                let w = p.static_weights();
                let w = if self.config.method.thresholds() {
                    w.thresholded(self.config.dynapix.gamma_add)
                } else {
                    w
                };
                (Some(w), background, mean)
            }
        };
        Ok(FrameMotion {
            t_wc,
            weights,
            background,
            gray,
            working,
            mean_probability,
            background_ms,
        })
    }

    /// Keeps a processed frame in the window (and its keyframe images), within the bounds.
    pub(super) fn remember(&mut self, past: Past) {
        self.window.push_back(past);
        let keep = self.config.online.window.max(self.past_reach());
        while self.window.len() > keep {
            if let Some(mut old) = self.window.pop_front()
                && old.keyframe
            {
                // Only the images (and the working depth) are needed as a source.
                old.background = None;
                old.gray = None;
                self.keyframes.push_back(old);
            }
        }
        while self.keyframes.len() > self.config.online.background_keyframes {
            self.keyframes.pop_front();
        }
    }

    /// The farthest past neighbour offset (moving term and rigidity cue).
    pub(super) fn past_reach(&self) -> usize {
        let rigidity = self
            .cues
            .is_some_and(|c| c.rigidity)
            .then_some(&self.config.motion.rigidity.offsets);
        self.config
            .online
            .past_offsets
            .iter()
            .chain(rigidity.into_iter().flatten().filter(|&&o| o < 0))
            .map(|o| o.unsigned_abs() as usize)
            .max()
            .unwrap_or(0)
    }

    /// The rigidity cue of frame `index` against the neighbours of `motion.rigidity.offsets`
    /// it has seen: past frames of the window, frames waiting in the lookahead.
    pub(super) fn rigidity(
        &self,
        index: usize,
        gray: &GrayImage,
        depth: &FloatImage,
    ) -> Result<FloatImage> {
        let sources = self.rigidity_sources(index, None);
        self.rigidity_from(gray, depth, &sources)
    }

    /// The neighbours of frame `index`'s rigidity cue that the system has, in the order the
    /// cue combines them (past frames, then waiting frames, each in the order of
    /// `motion.rigidity.offsets`): frames of the window, `in_flight` (the frame being
    /// tracked, not yet in the window) and frames waiting in the lookahead.
    pub(super) fn rigidity_sources<'a>(
        &'a self,
        index: usize,
        in_flight: Option<InFlight<'a>>,
    ) -> Vec<(i64, RigidSource<'a>)> {
        let mut seen = Vec::new();
        let mut waiting = Vec::new();
        for &o in &self.config.motion.rigidity.offsets {
            let Some(j) = index.checked_add_signed(o as isize) else {
                continue;
            };
            if o < 0 {
                if let Some(fl) = in_flight.filter(|fl| fl.index == j) {
                    seen.push((o, RigidSource::Seen(fl.gray.clone(), fl.images)));
                } else if let Some(p) = self.window.iter().find(|p| p.index == j)
                    && let Some(g) = &p.gray
                {
                    seen.push((o, RigidSource::Seen(g.clone(), &p.images)));
                }
            } else if let Some((_, f)) = self.pending.iter().find(|(k, _)| *k == j) {
                waiting.push((o, RigidSource::Waiting(f)));
            }
        }
        seen.extend(waiting);
        seen
    }

    /// The rigidity cue of a frame (`gray`, `depth`) against `sources`.
    pub(super) fn rigidity_from(
        &self,
        gray: &GrayImage,
        depth: &FloatImage,
        sources: &[(i64, RigidSource<'_>)],
    ) -> Result<FloatImage> {
        let waiting_grays: Vec<GrayImage> = sources
            .iter()
            .filter_map(|(_, s)| match s {
                RigidSource::Waiting(f) => Some(to_gray(&f.rgb)),
                RigidSource::Seen(..) => None,
            })
            .collect();
        let mut next_gray = waiting_grays.iter();
        let mut nbs: Vec<RigidFrame<'_>> = Vec::with_capacity(sources.len());
        for (o, s) in sources {
            match s {
                RigidSource::Seen(gray, images) => nbs.push(RigidFrame {
                    gray,
                    depth: &images.depth,
                    offset: *o,
                }),
                RigidSource::Waiting(f) => {
                    if let Some(gray) = next_gray.next() {
                        nbs.push(RigidFrame {
                            gray,
                            depth: &f.depth,
                            offset: *o,
                        });
                    }
                }
            }
        }
        if nbs.is_empty() {
            return Ok(FloatImage::new(self.cam.width, self.cam.height));
        }
        let me = RigidFrame {
            gray,
            depth,
            offset: 0,
        };
        let maps = dynapix_motion::rigidity_probability_with(
            &me,
            &nbs,
            &self.cam,
            &self.rigidity_flow,
            &self.config.motion.rigidity,
        )?;
        Ok(maps.p)
    }

    /// The rigidity cue of `frame`, to be pushed as frame `index` after the frame in flight,
    /// computed now; `shown`: the caller showed it before pushing it (a copy is kept to check
    /// the frame pushed). `None` when the method has no rigidity cue, or on any error (the
    /// frame's own push computes the cue again and reports it).
    pub(super) fn rigidity_ahead(
        &self,
        index: usize,
        frame: &RgbdFrame,
        shown: bool,
        in_flight: InFlight<'_>,
    ) -> Option<Ahead> {
        if !(self.config.online.rigidity_ahead && self.cues.is_some_and(|c| c.rigidity)) {
            return None;
        }
        let size = (self.cam.width, self.cam.height);
        if frame.rgb.dimensions() != size || frame.depth.dimensions() != size {
            return None;
        }
        let sources = self.rigidity_sources(index, Some(in_flight));
        let offsets = sources.iter().map(|(o, _)| *o).collect();
        let gray = to_gray(&frame.rgb);
        let map = self.rigidity_from(&gray, &frame.depth, &sources).ok()?;
        Some(Ahead {
            index,
            offsets,
            shown: shown.then(|| (frame.t, frame.rgb.clone(), frame.depth.clone())),
            map,
        })
    }

    /// The rigidity cue of frame `index` (`frame`) computed during the push before, if it
    /// was computed for this frame with the neighbours it has now; cleared either way.
    pub(super) fn take_ahead(&mut self, index: usize, frame: &RgbdFrame) -> Option<FloatImage> {
        let ahead = self.ahead.take()?;
        if ahead.index != index || ahead.shown.as_ref().is_some_and(|s| !same_frame(s, frame)) {
            return None;
        }
        let now: Vec<i64> = self
            .rigidity_sources(index, None)
            .iter()
            .map(|(o, _)| *o)
            .collect();
        (now == ahead.offsets).then_some(ahead.map)
    }

    /// The geometric cue of frame `index` (working depth `cur`, predicted pose `t_wc`): the
    /// static depth from the depths of the window, the kept keyframes and the waiting frames
    /// within `static_depth.window_s` seconds (at most `max_views`, newest first).
    pub(super) fn geometric(
        &self,
        index: usize,
        cur: &WorkingDepth,
        t_wc: &Se3,
    ) -> Result<FloatImage> {
        let params = &self.config.motion.static_depth;
        let t_cw = t_wc.inverse();
        let mut waiting: Vec<(WorkingDepth, Se3)> = Vec::new();
        for (j, f) in self.pending.iter().take(self.lookahead()) {
            if *j != index {
                waiting.push((
                    WorkingDepth::new(&f.depth, params),
                    self.predict_cw(*j).inverse(),
                ));
            }
        }
        let mut views: Vec<DepthView<'_>> = waiting
            .iter()
            .map(|(d, pose)| DepthView {
                depth: d,
                t_cs: t_cw * pose,
            })
            .collect();
        let newest_window = self.window.front().map_or(usize::MAX, |p| p.index);
        let kept = self.keyframes.iter().filter(|k| k.index < newest_window);
        for p in self.window.iter().rev().chain(kept.rev()) {
            if views.len() >= params.max_views {
                break;
            }
            if let Some(w) = &p.working {
                views.push(DepthView {
                    depth: w,
                    t_cs: t_cw * p.pose_wc,
                });
            }
        }
        if views.is_empty() {
            return Ok(FloatImage::new(self.cam.width, self.cam.height));
        }
        let sd = static_depth(&self.cam, &views, params)?;
        Ok(geometric_term(cur, &sd, params)?)
    }

    /// P of frame `index` from its background and neighbours.
    pub(super) fn motion(
        &self,
        index: usize,
        cur: &RgbdImages,
        bg: &StaticBackground,
        t_wc: &Se3,
        params: &MotionParams,
    ) -> Result<MotionProbability> {
        let t_cw = t_wc.inverse();
        // Past neighbours: processed frames with their tracked pose and kept background.
        let mut owned: Vec<(Arc<RgbdImages>, Arc<StaticBackground>, Se3)> = Vec::new();
        for &o in &self.config.online.past_offsets {
            let Some(j) = index.checked_sub(o.unsigned_abs() as usize) else {
                continue;
            };
            if let Some(p) = self.window.iter().find(|p| p.index == j)
                && let Some(b) = &p.background
            {
                owned.push((p.images.clone(), b.clone(), p.pose_wc));
            }
        }
        let nbs: Vec<Neighbour> = owned
            .iter()
            .map(|(img, b, pose)| Neighbour {
                frame: FrameImages {
                    rgb: &img.rgb,
                    depth: &img.depth,
                    background: &b.rgb,
                    background_depth: &b.depth,
                },
                t_cn: t_cw * pose,
            })
            .collect();
        let view = FrameImages {
            rgb: &cur.rgb,
            depth: &cur.depth,
            background: &bg.rgb,
            background_depth: &bg.depth,
        };
        let maps = motion_probability(&view, &nbs, &self.cam, &self.flow, params)?;
        Ok(MotionProbability::new(maps.p))
    }
}
