//! Typed, generational ids of the map's keyframes and map points. A leaf module: frames hold
//! ids of map points and the map hands them out, so both import them from here.

/// Id of a keyframe in the [`crate::map::Map`] (index + generation; a culled keyframe's id
/// goes stale).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct KeyFrameId {
    pub(crate) index: u32,
    pub(crate) generation: u32,
}

/// Id of a map point in the [`crate::map::Map`] (index + generation; a culled point's id goes
/// stale).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct MapPointId {
    pub(crate) index: u32,
    pub(crate) generation: u32,
}

impl KeyFrameId {
    /// Id of the `index`-th keyframe of a map rebuilt from dense storage (generation 0).
    pub(crate) fn dense(index: u32) -> Self {
        Self {
            index,
            generation: 0,
        }
    }

    /// The arena slot of the keyframe (shared with ids of culled keyframes of that slot).
    pub(crate) fn slot(self) -> usize {
        self.index as usize
    }
}

impl MapPointId {
    /// Id of the `index`-th point of a map rebuilt from dense storage (generation 0).
    pub(crate) fn dense(index: u32) -> Self {
        Self {
            index,
            generation: 0,
        }
    }
}
