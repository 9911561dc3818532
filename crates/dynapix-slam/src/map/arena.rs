//! A generational arena, the storage of the map's keyframes and map points.

struct Slot<T> {
    generation: u32,
    value: Option<T>,
}

/// A generational arena: removal bumps the slot generation, freed slots are reused in LIFO
/// order (deterministic).
pub(super) struct Arena<T> {
    slots: Vec<Slot<T>>,
    free: Vec<u32>,
    pub(super) len: usize,
}

impl<T> Arena<T> {
    pub(super) fn new() -> Self {
        Self {
            slots: Vec::new(),
            free: Vec::new(),
            len: 0,
        }
    }

    pub(super) fn insert(&mut self, value: T) -> (u32, u32) {
        self.len += 1;
        if let Some(i) = self.free.pop()
            && let Some(slot) = self.slots.get_mut(i as usize)
        {
            slot.value = Some(value);
            return (i, slot.generation);
        }
        self.slots.push(Slot {
            generation: 0,
            value: Some(value),
        });
        ((self.slots.len() - 1) as u32, 0)
    }

    pub(super) fn get(&self, index: u32, generation: u32) -> Option<&T> {
        self.slots
            .get(index as usize)
            .filter(|s| s.generation == generation)
            .and_then(|s| s.value.as_ref())
    }

    pub(super) fn get_mut(&mut self, index: u32, generation: u32) -> Option<&mut T> {
        self.slots
            .get_mut(index as usize)
            .filter(|s| s.generation == generation)
            .and_then(|s| s.value.as_mut())
    }

    pub(super) fn remove(&mut self, index: u32, generation: u32) -> Option<T> {
        let slot = self.slots.get_mut(index as usize)?;
        if slot.generation != generation {
            return None;
        }
        let v = slot.value.take()?;
        slot.generation = slot.generation.wrapping_add(1);
        self.free.push(index);
        self.len -= 1;
        Some(v)
    }

    /// An arena holding `values` at indices 0.. with generation 0 and no free slot.
    pub(super) fn from_values(values: Vec<T>) -> Self {
        let len = values.len();
        Self {
            slots: values
                .into_iter()
                .map(|v| Slot {
                    generation: 0,
                    value: Some(v),
                })
                .collect(),
            free: Vec::new(),
            len,
        }
    }

    pub(super) fn iter(&self) -> impl Iterator<Item = (u32, u32, &T)> {
        self.slots
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.value.as_ref().map(|v| (i as u32, s.generation, v)))
    }
}
