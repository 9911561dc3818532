//! Range checks of the configuration's own sections (the parameter structs of the
//! algorithm crates check themselves): every number has a range, errors name the key path.

use super::*;

impl Validate for Config {
    fn validate(&self) -> Checked {
        let m = self.mode.motion();
        let p = &self.motion.params;
        for (key, got) in [
            ("motion.params.mode", p.mode),
            ("motion.params.splat.mode", p.splat.mode),
            ("motion.params.moving.mode", p.moving.mode),
        ] {
            if got != m {
                return Err(InvalidParam::new(
                    key,
                    format!(
                        "is {got:?} but mode is {}: set only `mode` (paper or reference)",
                        self.mode.name()
                    ),
                ));
            }
        }
        let nested_dynapix = &self.slam.params.map.dynapix;
        if *nested_dynapix != DynaPixParams::new(self.mode.weighting())
            && *nested_dynapix != self.dynapix.params(self.mode.weighting())
        {
            return Err(InvalidParam::new(
                "slam.params.map.dynapix",
                format!(
                    "is {nested_dynapix:?}, which neither the section `dynapix` nor mode {} \
                     gives: set dynapix.gamma_add, dynapix.gamma_del, dynapix.update (and \
                     `mode` for the weighting) instead",
                    self.mode.name()
                ),
            ));
        }
        nested("sequence", &self.sequence)?;
        nested("dynapix", &self.dynapix)?;
        nested("motion", &self.motion)?;
        nested("slam.params", &self.slam.params)?;
        nested("passes", &self.passes)?;
        nested("online", &self.online)?;
        if self.method.terms().is_some() {
            let c = self.cues();
            if !(c.paper || c.geometric || c.rigidity) {
                return Err(InvalidParam::new(
                    "motion.cues",
                    "every cue is off; enable at least one of paper, geometric, rigidity (or \
                     use method orbslam2)",
                ));
            }
        }
        Ok(())
    }
}

impl Validate for SequenceConfig {
    fn validate(&self) -> Checked {
        above("max_diff", self.max_diff, 0.0, 10.0)?;
        optional("max_frames", self.max_frames, 1, 100_000_000)?;
        // 1 TiB: more than any machine this runs on.
        range("decoded_cache_mib", self.decoded_cache_mib, 0, 1 << 20)?;
        if let Some(Some(v)) = self.depth_saturation.stated() {
            range("depth_saturation", v, 1, u16::MAX)?;
        }
        match self.max_depth.stated() {
            Some(m) => above("max_depth", m, 0.0, 1000.0),
            None => Ok(()),
        }
    }
}

impl Validate for MotionConfig {
    fn validate(&self) -> Checked {
        nested("params", &self.params)?;
        nested("reconstruct", &self.reconstruct)?;
        range("max_pose_gap", self.max_pose_gap, 0.0, 60.0)?;
        nested("static_depth", &self.static_depth)?;
        nested("rigidity", &self.rigidity)
    }
}

impl Validate for PassConfig {
    fn validate(&self) -> Checked {
        range("weighted", self.weighted, 1, 10)
    }
}

impl Validate for OnlineConfig {
    fn validate(&self) -> Checked {
        range("lookahead", self.lookahead, 0, 300)?;
        range("window", self.window, 1, 1000)?;
        range("background_keyframes", self.background_keyframes, 0, 1000)?;
        // The moving term uses past neighbours only.
        each("past_offsets", &self.past_offsets, (0, 16), -60, -1)?;
        range(
            "rigidity_flow_working_width",
            self.rigidity_flow_working_width,
            0,
            16_384,
        )?;
        if let Some(p) = &self.rigidity_flow {
            nested("rigidity_flow", p)?;
        }
        Ok(())
    }
}
