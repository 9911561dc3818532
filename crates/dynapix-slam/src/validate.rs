//! The ranges of the SLAM parameters ([`dynapix_params::Validate`]), checked before a run
//! starts: counts bounded so memory and time stay finite (a rotation histogram of at most
//! 360 bins, at most 100 pose-optimisation rounds, 1000 iterations), ratios and
//! probabilities in [0, 1], χ² thresholds and search radii positive, DynaPix's γ_del above 0
//! (at 0 every map point would be removed on its first observation, so nothing is tracked).

use dynapix_params::{Checked, Validate, above, nested, optional, probability, range};

use crate::local_mapping::LocalMappingParams;
use crate::loop_closing::LoopClosingParams;
use crate::loop_closing::correct::CorrectionParams;
use crate::loop_closing::detect::DetectionParams;
use crate::map::MapParams;
use crate::matcher::MatcherParams;
use crate::system::SystemParams;
use crate::tracking::{RelocParams, TrackingParams};
use crate::weighting::{DynaPixParams, ProbUpdate};

/// Largest match, inlier or feature count a threshold may ask for.
const MAX_COUNT: usize = 100_000;
/// Largest χ² threshold.
const MAX_CHI2: f64 = 1e6;
/// Largest search-radius factor.
const MAX_RADIUS: f32 = 1000.0;
/// Largest iteration count of a refinement or a RANSAC.
const MAX_ITERATIONS: usize = 100_000;
/// Largest frame or keyframe count of a schedule.
const MAX_FRAMES: u64 = 1_000_000;
/// Deepest vocabulary level features may be grouped at.
const MAX_BOW_DEPTH: usize = 16;

impl Validate for MatcherParams {
    fn validate(&self) -> Checked {
        // Descriptors are 256 bits: a Hamming distance lies in [0, 256].
        range("th_high", self.th_high, 0, 256)?;
        range("th_low", self.th_low, 0, 256)?;
        range("histo_len", self.histo_len, 1, 360)?;
        probability("histo_min_ratio", self.histo_min_ratio)
    }
}

impl Validate for RelocParams {
    fn validate(&self) -> Checked {
        above("ratio", self.ratio, 0.0, 1.0)?;
        range("min_matches", self.min_matches, 0, MAX_COUNT)?;
        above("probability", self.probability, 0.0, 1.0)?;
        range("min_inliers", self.min_inliers, 0, MAX_COUNT)?;
        range("max_iterations", self.max_iterations, 1, MAX_ITERATIONS)?;
        above("chi2", self.chi2, 0.0, MAX_CHI2)?;
        range(
            "max_candidates_without_vocabulary",
            self.max_candidates_without_vocabulary,
            0,
            10_000,
        )?;
        probability("min_common_words_ratio", self.min_common_words_ratio)?;
        probability("min_score_ratio", self.min_score_ratio)
    }
}

impl Validate for TrackingParams {
    fn validate(&self) -> Checked {
        range("init_min_features", self.init_min_features, 0, MAX_COUNT)?;
        above("motion_th", self.motion_th, 0.0, MAX_RADIUS)?;
        range("motion_min_matches", self.motion_min_matches, 0, MAX_COUNT)?;
        range("min_inliers_frame", self.min_inliers_frame, 0, MAX_COUNT)?;
        above("ref_ratio", self.ref_ratio, 0.0, 1.0)?;
        range("ref_min_matches", self.ref_min_matches, 0, MAX_COUNT)?;
        above("local_ratio", self.local_ratio, 0.0, 1.0)?;
        above("local_th", self.local_th, 0.0, MAX_RADIUS)?;
        above("local_th_reloc", self.local_th_reloc, 0.0, MAX_RADIUS)?;
        range("local_min_inliers", self.local_min_inliers, 0, MAX_COUNT)?;
        range(
            "local_min_inliers_reloc",
            self.local_min_inliers_reloc,
            0,
            MAX_COUNT,
        )?;
        range("view_cos_min", self.view_cos_min, -1.0, 1.0)?;
        range("max_local_keyframes", self.max_local_keyframes, 1, 10_000)?;
        probability("kf_ref_ratio", self.kf_ref_ratio)?;
        probability("kf_ref_ratio_few", self.kf_ref_ratio_few)?;
        probability("kf_c1c_ratio", self.kf_c1c_ratio)?;
        range("kf_min_inliers", self.kf_min_inliers, 0, MAX_COUNT)?;
        range("kf_close_tracked", self.kf_close_tracked, 0, MAX_COUNT)?;
        range("kf_close_untracked", self.kf_close_untracked, 0, MAX_COUNT)?;
        range("min_frames", self.min_frames, 0, MAX_FRAMES)?;
        range("kf_new_points", self.kf_new_points, 0, MAX_COUNT)?;
        range("bow_group_depth", self.bow_group_depth, 0, MAX_BOW_DEPTH)?;
        range(
            "reset_max_keyframes",
            self.reset_max_keyframes,
            0,
            1_000_000,
        )?;
        nested("pose", &self.pose)?;
        nested("matcher", &self.matcher)?;
        nested("reloc", &self.reloc)?;
        range("predicted_frames", self.predicted_frames, 0, MAX_FRAMES)?;
        above("local_reloc_th", self.local_reloc_th, 0.0, MAX_RADIUS)
    }
}

impl Validate for LocalMappingParams {
    fn validate(&self) -> Checked {
        probability("cull_found_ratio", self.cull_found_ratio)?;
        range("cull_max_obs", self.cull_max_obs, 0, 1000)?;
        range("cull_age", self.cull_age, 0, MAX_FRAMES)?;
        range("recent_window", self.recent_window, 0, MAX_FRAMES)?;
        range(
            "triangulation_neighbours",
            self.triangulation_neighbours,
            0,
            1000,
        )?;
        above("ratio_factor_slack", self.ratio_factor_slack, 0.0, 100.0)?;
        above("chi2_mono", self.chi2_mono, 0.0, MAX_CHI2)?;
        above("chi2_stereo", self.chi2_stereo, 0.0, MAX_CHI2)?;
        range("fuse_neighbours", self.fuse_neighbours, 0, 1000)?;
        range("fuse_second", self.fuse_second, 0, 1000)?;
        above("fuse_th", self.fuse_th, 0.0, MAX_RADIUS)?;
        range("ba_min_keyframes", self.ba_min_keyframes, 0, 1_000_000)?;
        probability("kf_redundancy", self.kf_redundancy)?;
        range("kf_cull_observers", self.kf_cull_observers, 0, 1000)?;
        range("bow_group_depth", self.bow_group_depth, 0, MAX_BOW_DEPTH)?;
        range(
            "ba_max_local_keyframes",
            self.ba_max_local_keyframes,
            1,
            10_000,
        )?;
        range("ba_min_interval_s", self.ba_min_interval_s, 0.0, 3600.0)?;
        nested("ba", &self.ba)?;
        nested("matcher", &self.matcher)
    }
}

impl Validate for DynaPixParams {
    fn validate(&self) -> Checked {
        probability("gamma_add", self.gamma_add)?;
        above("gamma_del", self.gamma_del, 0.0, 1.0)?;
        if let ProbUpdate::Ema { alpha } = self.update {
            above("update.ema.alpha", alpha, 0.0, 1.0)?;
        }
        Ok(())
    }
}

impl Validate for MapParams {
    fn validate(&self) -> Checked {
        range(
            "covisibility_threshold",
            self.covisibility_threshold,
            0,
            MAX_COUNT,
        )?;
        nested("dynapix", &self.dynapix)
    }
}

impl Validate for DetectionParams {
    fn validate(&self) -> Checked {
        range(
            "min_keyframes_since_loop",
            self.min_keyframes_since_loop,
            0,
            MAX_FRAMES,
        )?;
        probability("common_words_ratio", self.common_words_ratio)?;
        probability("accumulated_score_ratio", self.accumulated_score_ratio)?;
        range(
            "accumulation_covisibles",
            self.accumulation_covisibles,
            0,
            1000,
        )?;
        range("consistency_threshold", self.consistency_threshold, 0, 1000)?;
        above("bow_ratio", self.bow_ratio, 0.0, 1.0)?;
        range("min_bow_matches", self.min_bow_matches, 0, MAX_COUNT)?;
        above("ransac_probability", self.ransac_probability, 0.0, 1.0)?;
        range("ransac_min_inliers", self.ransac_min_inliers, 0, MAX_COUNT)?;
        range(
            "ransac_max_iterations",
            self.ransac_max_iterations,
            1,
            MAX_ITERATIONS,
        )?;
        range(
            "ransac_iterations_per_turn",
            self.ransac_iterations_per_turn,
            1,
            MAX_ITERATIONS,
        )?;
        above("ransac_chi2", self.ransac_chi2, 0.0, MAX_CHI2)?;
        above("se3_search_radius", self.se3_search_radius, 0.0, MAX_RADIUS)?;
        above("refine_chi2", self.refine_chi2, 0.0, MAX_CHI2)?;
        above("refine_chi2_depth", self.refine_chi2_depth, 0.0, MAX_CHI2)?;
        range(
            "refine_first_iterations",
            self.refine_first_iterations,
            0,
            1000,
        )?;
        range(
            "refine_iterations_after_drop",
            self.refine_iterations_after_drop,
            0,
            1000,
        )?;
        range("refine_iterations", self.refine_iterations, 0, 1000)?;
        range("refine_min_pairs", self.refine_min_pairs, 0, MAX_COUNT)?;
        range(
            "min_refined_inliers",
            self.min_refined_inliers,
            0,
            MAX_COUNT,
        )?;
        above("projection_radius", self.projection_radius, 0.0, MAX_RADIUS)?;
        range("min_total_matches", self.min_total_matches, 0, MAX_COUNT)?;
        nested("matcher", &self.matcher)
    }
}

impl Validate for CorrectionParams {
    fn validate(&self) -> Checked {
        above("fuse_radius", self.fuse_radius, 0.0, MAX_RADIUS)?;
        nested("matcher", &self.matcher)?;
        range(
            "essential_graph_min_weight",
            self.essential_graph_min_weight,
            0,
            MAX_COUNT,
        )?;
        range(
            "essential_graph_iterations",
            self.essential_graph_iterations,
            0,
            1000,
        )?;
        range("global_ba_iterations", self.global_ba_iterations, 0, 1000)?;
        nested("ba", &self.ba)
    }
}

impl Validate for LoopClosingParams {
    fn validate(&self) -> Checked {
        nested("detection", &self.detection)?;
        nested("correction", &self.correction)
    }
}

impl Validate for SystemParams {
    fn validate(&self) -> Checked {
        nested("tracking", &self.tracking)?;
        nested("mapping", &self.mapping)?;
        nested("map", &self.map)?;
        nested("loop_closing", &self.loop_closing)?;
        optional(
            "static_features_min_weight",
            self.static_features_min_weight,
            0.0,
            1.0,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_pass_and_errors_name_the_key_path() {
        SystemParams::default().validate().unwrap();
        let mut p = SystemParams::default();
        p.tracking.pose.rounds = 1_000_000_000_000;
        let e = p.validate().unwrap_err();
        assert_eq!(e.key, "tracking.pose.rounds");
        let mut p = SystemParams::default();
        p.mapping.matcher.histo_len = 1_000_000_000_000;
        assert_eq!(
            p.validate().unwrap_err().to_string(),
            "mapping.matcher.histo_len must lie in [1, 360], got 1000000000000"
        );
        let mut p = SystemParams::default();
        p.map.dynapix.gamma_del = 0.0;
        assert_eq!(p.validate().unwrap_err().key, "map.dynapix.gamma_del");
        let mut p = SystemParams::default();
        p.loop_closing.detection.ransac_probability = -1.0;
        assert_eq!(
            p.validate().unwrap_err().key,
            "loop_closing.detection.ransac_probability"
        );
    }
}
