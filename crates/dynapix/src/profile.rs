//! Where the time of a run goes (`dynapix bench`).
//!
//! The pipeline marks its work with `tracing` spans: **stages** (target [`STAGE_TARGET`]:
//! image decoding, ORB extraction, tracking, local mapping, loop closing, each flow, splatting,
//! background, the cues, map I/O) and **phases** (target [`PHASE_TARGET`]: SLAM passes,
//! rigidity maps, motion maps). A [`StageProfiler`] installed as a layer of the global
//! subscriber sums, per span name, the wall time spent inside the span over every entry on
//! every thread: for stages run per frame on parallel workers (flows, cues) that is their
//! busy time summed over the workers; a stage that fans its own work out to worker threads
//! (ORB extraction, bundle adjustment) counts its duration once. Phases are entered on the
//! calling thread: their figure is the phase's duration. Time descheduled counts too, so
//! measure on a quiet machine. Without a profiler the spans cost a callsite check.
//!
//! ```no_run
//! use tracing_subscriber::layer::SubscriberExt;
//! use tracing_subscriber::util::SubscriberInitExt;
//!
//! let profiler = dynapix::bench::StageProfiler::new();
//! tracing_subscriber::registry().with(profiler.layer()).init();
//! profiler.start();
//! // ... run the pipeline ...
//! for s in profiler.stop().stages {
//!     println!("{}: {:.3} s in {} calls", s.name, s.seconds, s.calls);
//! }
//! ```

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;
use tracing::span::{Attributes, Id};
use tracing::{Metadata, Subscriber};
use tracing_subscriber::Layer;
use tracing_subscriber::layer::{Context, Filter};
use tracing_subscriber::registry::LookupSpan;

/// Target of the spans that mark a stage of work (summed over threads).
pub const STAGE_TARGET: &str = "dynapix::stage";
/// Target of the spans that mark a phase of a run (wall time on the calling thread).
pub const PHASE_TARGET: &str = "dynapix::phase";

/// Time spent in one stage or phase.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct StageTime {
    /// The span name (e.g. `orb extraction`, `rigidity: flow`).
    pub name: String,
    /// Wall-clock seconds inside the span, summed over every entry on every thread.
    pub seconds: f64,
    /// Number of times the span was entered.
    pub calls: u64,
}

/// What a profiler measured between [`StageProfiler::start`] and [`StageProfiler::stop`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Profile {
    /// Phases, by name.
    pub phases: Vec<StageTime>,
    /// Stages, by name.
    pub stages: Vec<StageTime>,
}

#[derive(Default)]
struct Table {
    /// (is a phase, name) → (wall time, entries).
    rows: BTreeMap<(bool, &'static str), (Duration, u64)>,
}

#[derive(Default)]
struct Inner {
    enabled: AtomicBool,
    table: Mutex<Table>,
}

/// Sums the time spent in the pipeline's stage and phase spans (see the module
/// documentation). Cheap to clone: clones share one table.
#[derive(Clone, Default)]
pub struct StageProfiler {
    inner: Arc<Inner>,
}

/// When a span was entered (kept in the span's extensions).
struct Entered(Instant);

impl StageProfiler {
    /// A profiler that measures nothing until [`StageProfiler::start`].
    pub fn new() -> Self {
        Self::default()
    }

    /// The layer to add to the global subscriber (filtered to the stage and phase spans, so
    /// it leaves every other layer's filtering alone).
    pub fn layer<S>(&self) -> impl Layer<S> + Send + Sync + 'static
    where
        S: Subscriber + for<'a> LookupSpan<'a>,
    {
        self.clone().with_filter(ProfiledSpans)
    }

    /// Clears the table and starts measuring.
    pub fn start(&self) {
        if let Ok(mut t) = self.inner.table.lock() {
            t.rows.clear();
        }
        self.inner.enabled.store(true, Ordering::SeqCst);
    }

    /// Stops measuring and returns what was measured since [`StageProfiler::start`].
    pub fn stop(&self) -> Profile {
        self.inner.enabled.store(false, Ordering::SeqCst);
        let rows = match self.inner.table.lock() {
            Ok(mut t) => std::mem::take(&mut t.rows),
            Err(_) => BTreeMap::new(),
        };
        let mut out = Profile::default();
        for ((phase, name), (d, calls)) in rows {
            let row = StageTime {
                name: name.to_string(),
                seconds: d.as_secs_f64(),
                calls,
            };
            if phase {
                out.phases.push(row);
            } else {
                out.stages.push(row);
            }
        }
        out
    }

    fn enabled(&self) -> bool {
        self.inner.enabled.load(Ordering::Relaxed)
    }
}

/// The per-layer filter of [`StageProfiler::layer`]: stage and phase spans only.
struct ProfiledSpans;

fn is_profiled(meta: &Metadata<'_>) -> bool {
    meta.is_span() && (meta.target() == STAGE_TARGET || meta.target() == PHASE_TARGET)
}

impl<S> Filter<S> for ProfiledSpans {
    fn enabled(&self, meta: &Metadata<'_>, _: &Context<'_, S>) -> bool {
        is_profiled(meta)
    }

    fn callsite_enabled(&self, meta: &'static Metadata<'static>) -> tracing::subscriber::Interest {
        if is_profiled(meta) {
            tracing::subscriber::Interest::always()
        } else {
            tracing::subscriber::Interest::never()
        }
    }
}

impl<S> Layer<S> for StageProfiler
where
    S: Subscriber + for<'a> LookupSpan<'a>,
{
    fn on_new_span(&self, _: &Attributes<'_>, _: &Id, _: Context<'_, S>) {}

    fn on_enter(&self, id: &Id, ctx: Context<'_, S>) {
        if !self.enabled() {
            return;
        }
        if let Some(span) = ctx.span(id) {
            span.extensions_mut().replace(Entered(Instant::now()));
        }
    }

    fn on_exit(&self, id: &Id, ctx: Context<'_, S>) {
        let Some(span) = ctx.span(id) else {
            return;
        };
        let Some(Entered(at)) = span.extensions_mut().remove::<Entered>() else {
            return;
        };
        if !self.enabled() {
            return;
        }
        let meta = span.metadata();
        let key = (meta.target() == PHASE_TARGET, meta.name());
        let wall = at.elapsed();
        if let Ok(mut t) = self.inner.table.lock() {
            let row = t.rows.entry(key).or_default();
            row.0 += wall;
            row.1 += 1;
        }
    }
}

pub(crate) use dynapix_io::usage::process_usage;

/// Threshold (bytes) below which [`retain_freed_memory`] has glibc serve allocations from its
/// heap: 32 MiB, glibc's largest allowed value on 64-bit targets.
pub const HEAP_ALLOCATION_LIMIT: usize = 32 << 20;
/// Free memory at the top of a glibc heap that [`retain_freed_memory`] lets glibc keep
/// instead of returning it to the kernel: 1 GiB.
pub const RETAINED_FREE_MEMORY: usize = 1 << 30;

/// Tells glibc's allocator to keep freed memory for reuse: allocations up to 32 MiB
/// (`HEAP_ALLOCATION_LIMIT`) come from its heaps instead of fresh `mmap`s, and free memory up
/// to 1 GiB (`RETAINED_FREE_MEMORY`) stays there instead of being returned to the kernel.
///
/// A DynaPix run allocates and frees images, flows and pyramids of one to a few megabytes per
/// frame on every thread. With glibc's defaults many of them are mapped and unmapped each
/// time, and every page of the next one is faulted in and zeroed by the kernel again (on synth
/// walking_xyz 640×480 online: 544 000 page faults and 1.45 s of system time in a 20 s run).
/// Meant for programs (the `dynapix` binary calls it first thing); it changes the whole
/// process's allocator, never results. Returns `false` where there is nothing to tune (not
/// Linux with glibc) or glibc refused a value.
pub fn retain_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        let mmap = HEAP_ALLOCATION_LIMIT as libc::c_int;
        let trim = RETAINED_FREE_MEMORY as libc::c_int;
        // SAFETY: mallopt only sets allocator parameters; both values are in glibc's range.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, mmap) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, trim) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracing_subscriber::layer::SubscriberExt;

    fn busy(ms: u64) {
        let t = Instant::now();
        while t.elapsed() < Duration::from_millis(ms) {
            std::hint::spin_loop();
        }
    }

    #[test]
    fn stages_sum_over_entries_and_threads_phases_are_separate() {
        let profiler = StageProfiler::new();
        let subscriber = tracing_subscriber::registry().with(profiler.layer());
        let dispatch = tracing::Dispatch::new(subscriber);
        // Not measured: before start.
        tracing::dispatcher::with_default(&dispatch, || {
            let _s = tracing::info_span!(target: "dynapix::stage", "a").entered();
            busy(5);
        });
        profiler.start();
        std::thread::scope(|scope| {
            for _ in 0..2 {
                let d = dispatch.clone();
                scope.spawn(move || {
                    tracing::dispatcher::with_default(&d, || {
                        let _p = tracing::info_span!(target: "dynapix::phase", "p").entered();
                        for _ in 0..3 {
                            let _s = tracing::info_span!(target: "dynapix::stage", "a").entered();
                            busy(4);
                        }
                        // Other targets are not measured.
                        let _o = tracing::info_span!(target: "elsewhere", "b").entered();
                        busy(2);
                    });
                });
            }
        });
        let p = profiler.stop();
        assert_eq!(p.stages.len(), 1, "{p:?}");
        assert_eq!(p.stages[0].name, "a");
        assert_eq!(p.stages[0].calls, 6);
        assert!(p.stages[0].seconds >= 0.024, "{p:?}");
        assert_eq!(p.phases.len(), 1);
        assert_eq!(p.phases[0].calls, 2);
        assert!(p.phases[0].seconds >= p.stages[0].seconds, "{p:?}");
        // Stopped: nothing more is measured.
        tracing::dispatcher::with_default(&dispatch, || {
            let _s = tracing::info_span!(target: "dynapix::stage", "a").entered();
        });
        assert_eq!(profiler.stop(), Profile::default());
    }
}
