//! DynaPix inside the SLAM backend (paper §3.2; reference behaviour spec §2, fixes spec §7
//! items 13–18 and 23): the weighting configuration and the per-keypoint / per-map-point rules
//! the tracker and local mapping call.
//!
//! - Per-keypoint weight w = 1 − P is sampled once in [`crate::frame::Frame::new`] at the
//!   keypoint's image (distorted) position with bounds checks; keypoints with w = 0
//!   (P > 0.999 after the reference's 16-bit quantisation) are dropped there.
//! - Map-point birth ([`may_birth`]): one gate P ≤ γ_add at every source of new points
//!   (initial map, tracking keyframes, triangulation, fusion) in `paper` mode; in `reference`
//!   mode only tracking keyframes are gated, with the reference's exact `w == 1` test
//!   (spec §2.5). Semantic masks (DynaPix+) block birth in both modes.
//! - Per-map-point motion probability ([`update_point_probability`]) from the keypoints it is
//!   matched to in tracked frames, and removal when it reaches γ_del ([`should_delete`]).
//! - Fine optimisation: weights clamped to [1 − γ_del, 1] ([`ba_weight_clamp`]), outlier
//!   tests on unweighted residuals (`paper`, via [`dynapix_optim::WeightMode::Paper`]).
//!
//! Two layers: [`params`] holds the parameters and the rules on plain values and sits below
//! the frame and the map (the map keeps [`DynaPixParams`] in its parameters); [`apply`]
//! applies the rules to frames and the map and sits above both.

pub mod apply;
pub mod params;

pub use apply::{
    UpdateStats, apply_class_mask, may_birth_in_frame, may_birth_in_keyframe,
    update_matched_points, update_matched_points_logged,
};
pub use params::{
    BirthSource, DynaPixParams, ProbUpdate, Weighting, ba_params, ba_weight_clamp, may_birth,
    pose_params, prob_of_weight, should_delete, update_point_probability, weight_mode,
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::MapParams;
    use crate::system::SystemParams;
    use crate::tracking::TrackingParams;
    use dynapix_optim::WeightMode;

    #[test]
    fn birth_gate_follows_gamma_add_and_masks() {
        let p = DynaPixParams::default();
        for s in [
            BirthSource::Initialization,
            BirthSource::TrackingKeyFrame,
            BirthSource::Triangulation,
            BirthSource::Fusion,
        ] {
            assert!(may_birth(&p, 1.0, false, s));
            assert!(may_birth(&p, 0.96, false, s), "P = 0.04 ≤ γ_add");
            assert!(!may_birth(&p, 0.94, false, s), "P = 0.06 > γ_add");
            assert!(!may_birth(&p, 1.0, true, s), "semantic mask blocks birth");
        }
        let r = DynaPixParams::new(Weighting::Reference);
        assert!(!may_birth(&r, 0.999, false, BirthSource::TrackingKeyFrame));
        assert!(may_birth(&r, 1.0, false, BirthSource::TrackingKeyFrame));
        assert!(
            may_birth(&r, 0.2, false, BirthSource::Triangulation),
            "ungated source"
        );
        let off = DynaPixParams::new(Weighting::Off);
        assert!(may_birth(&off, 0.0, false, BirthSource::TrackingKeyFrame));
    }

    #[test]
    fn deletion_at_gamma_del() {
        let p = DynaPixParams::default();
        assert!(!should_delete(&p, 0.099));
        assert!(should_delete(&p, 0.1));
        let r = DynaPixParams::new(Weighting::Reference);
        assert!(!should_delete(&r, 0.1));
        assert!(should_delete(&r, 0.101));
        assert!(!should_delete(&DynaPixParams::new(Weighting::Off), 1.0));
    }

    #[test]
    fn update_rules() {
        let ema = ProbUpdate::Ema { alpha: 0.5 };
        // A static point observed once on a mover (P = 0.3) crosses γ_del at once …
        assert!(update_point_probability(ema, 0.0, 0.3) >= 0.1);
        // … a single slightly noisy observation (P = 0.15) does not.
        let q = update_point_probability(ema, 0.0, 0.15);
        assert!(q < 0.1, "{q}");
        // Repeated noise does.
        let q2 = update_point_probability(ema, q, 0.15);
        assert!(q2 >= 0.1, "{q2}");
        assert_eq!(update_point_probability(ProbUpdate::Max, 0.2, 0.1), 0.2);
        assert_eq!(update_point_probability(ProbUpdate::Latest, 0.2, 0.1), 0.1);
    }

    #[test]
    fn clamp_and_modes_configure_the_stages() {
        let s = SystemParams::default().with_dynapix(DynaPixParams::default());
        let ba = ba_params(&s.mapping.ba, &s.map.dynapix);
        let (lo, hi) = ba.weight_clamp.expect("paper mode clamps");
        assert!((lo - 0.9).abs() < 1e-6 && hi == 1.0, "[{lo}, {hi}]");
        assert_eq!(ba.weight_mode, WeightMode::Paper);
        assert_eq!(
            SystemParams::default(),
            s,
            "the default is the paper mode, consistently"
        );
        let r = SystemParams::default().with_dynapix(DynaPixParams::new(Weighting::Reference));
        assert_eq!(ba_params(&r.mapping.ba, &r.map.dynapix).weight_clamp, None);
        assert_eq!(
            pose_params(&r.tracking.pose, &r.map.dynapix).weight_mode,
            WeightMode::Reference
        );
        assert_eq!(r.map.dynapix.weighting, Weighting::Reference);
        let off = DynaPixParams::new(Weighting::Off);
        assert_eq!(ba_params(&r.mapping.ba, &off).weight_clamp, None);
        assert_eq!(
            ba_params(&r.mapping.ba, &off).weight_mode,
            WeightMode::Paper
        );
    }

    #[test]
    fn parameters_round_trip_through_json_and_missing_fields_take_defaults() {
        let mut s = SystemParams::default().with_dynapix(DynaPixParams::new(Weighting::Reference));
        s.tracking.motion_th = 12.5;
        s.loop_closing.enabled = false;
        let text = serde_json::to_string(&s).unwrap();
        let back: SystemParams = serde_json::from_str(&text).unwrap();
        assert_eq!(back, s);
        let partial: SystemParams =
            serde_json::from_str(r#"{"tracking": {"motion_th": 9.0}}"#).unwrap();
        assert_eq!(partial.tracking.motion_th, 9.0);
        assert_eq!(
            partial.tracking.local_th,
            TrackingParams::default().local_th
        );
        assert_eq!(partial.map, MapParams::default());
    }
}
