//! Streaming read-ahead: frames loaded on reader threads a few frames before the consumer
//! takes them, in order.

use super::Input;

impl Input {
    /// Streams frames `0..len()` in order as a camera driver would: `load(i)` runs on a reader
    /// thread up to `ahead` frames before `consume` takes frame `i`, so decoding overlaps the
    /// processing of the frames before. The first error of `consume` stops the stream and is
    /// returned (the reader stops at the next frame).
    pub fn stream<T: Send, E>(
        &self,
        ahead: usize,
        load: impl FnMut(usize) -> T + Send,
        mut consume: impl FnMut(usize, T) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        self.stream_inner(ahead, load, false, |i, item, _| consume(i, item))
    }

    /// [`Input::stream`] that also shows `consume` the next frame's item when the reader has
    /// already delivered it (`None` when it has not, or at the end): never waits for it, so
    /// a consumer that uses it to start on the next frame early (e.g.
    /// [`crate::OnlineDynaPix::push_before`]) adds no latency.
    pub fn stream_with_next<T: Send, E>(
        &self,
        ahead: usize,
        load: impl FnMut(usize) -> T + Send,
        consume: impl FnMut(usize, T, Option<&T>) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        self.stream_inner(ahead, load, true, consume)
    }

    /// The reader thread and the consuming loop of [`Input::stream`] and
    /// [`Input::stream_with_next`]; `peek`: take the next item if it has arrived.
    fn stream_inner<T: Send, E>(
        &self,
        ahead: usize,
        mut load: impl FnMut(usize) -> T + Send,
        peek: bool,
        mut consume: impl FnMut(usize, T, Option<&T>) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        let n = self.len();
        std::thread::scope(|scope| {
            let (tx, rx) = std::sync::mpsc::sync_channel::<(usize, T)>(ahead.max(1));
            scope.spawn(move || {
                for i in 0..n {
                    if tx.send((i, load(i))).is_err() {
                        break;
                    }
                }
            });
            let mut held: Option<(usize, T)> = None;
            loop {
                let (i, item) = match held.take() {
                    Some(x) => x,
                    None => match rx.recv() {
                        Ok(x) => x,
                        Err(_) => break,
                    },
                };
                let next = if peek { rx.try_recv().ok() } else { None };
                consume(i, item, next.as_ref().map(|(_, t)| t))?;
                held = next;
            }
            Ok(())
        })
    }

    /// [`Input::stream`] with `readers` reader threads: reader `r` loads the frames
    /// `r, r + readers, …` with its own `make_load()`, each up to `ahead` frames before
    /// `consume` takes them, so the loading of consecutive frames overlaps when one reader
    /// cannot keep up (decoding, weight maps, feature extraction of a SLAM pass). `consume`
    /// still takes every frame in order, so the result depends only on what `load` returns
    /// for each frame, never on the number of readers or on timing. The first error of
    /// `consume` stops the stream and is returned (each reader stops at its next frame).
    pub fn stream_parallel<T: Send, L, E>(
        &self,
        ahead: usize,
        readers: usize,
        make_load: impl Fn() -> L,
        mut consume: impl FnMut(usize, T) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E>
    where
        L: FnMut(usize) -> T + Send,
    {
        let n = self.len();
        let readers = readers.clamp(1, n.max(1));
        std::thread::scope(|scope| {
            let mut rxs = Vec::with_capacity(readers);
            for r in 0..readers {
                let (tx, rx) = std::sync::mpsc::sync_channel::<(usize, T)>(ahead.max(1));
                let mut load = make_load();
                scope.spawn(move || {
                    for i in (r..n).step_by(readers) {
                        if tx.send((i, load(i))).is_err() {
                            break;
                        }
                    }
                });
                rxs.push(rx);
            }
            for i in 0..n {
                let Ok((j, item)) = rxs[i % readers].recv() else {
                    break;
                };
                debug_assert_eq!(i, j, "reader {} sent frame {j} for {i}", i % readers);
                consume(i, item)?;
            }
            Ok(())
        })
    }
}
