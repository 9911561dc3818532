//! The viewer layout sent with a recording: the 3D world (camera frustum with its image,
//! trajectories, map) on the left; the image with P and keypoints, and the depth, in the
//! middle; plots and events on the right; the time panel on the pass being logged.

use rerun::blueprint::components::PanelState;
use rerun::blueprint::{
    Blueprint, BlueprintPanel, Horizontal, SelectionPanel, Spatial2DView, Spatial3DView,
    TextLogView, TimePanel, TimeSeriesView, Vertical,
};

/// The layout, with the time panel on `timeline` (the pass being logged, e.g. `pass2`).
pub fn blueprint(timeline: &str) -> Blueprint {
    let world = Spatial3DView::new("world (camera, trajectories, map)").with_origin("world");
    let image = Spatial2DView::new("rgb + P (red) + keypoints").with_origin("world/camera/image");
    let depth = Spatial2DView::new("depth").with_origin("depth");
    let tracking = TimeSeriesView::new("tracking").with_origin("plots");
    let timings = TimeSeriesView::new("stage timings (ms)").with_origin("timings");
    let events = TextLogView::new("events").with_origin("events");
    Blueprint::new(
        Horizontal::new([
            world.into(),
            Vertical::new([image.into(), depth.into()]).into(),
            Vertical::new([tracking.into(), timings.into(), events.into()]).into(),
        ])
        .with_column_shares([0.45, 0.3, 0.25]),
    )
    .with_blueprint_panel(BlueprintPanel::new().with_state(PanelState::Collapsed))
    .with_selection_panel(SelectionPanel::new().with_state(PanelState::Collapsed))
    .with_time_panel(TimePanel::new().with_timeline(timeline))
}
