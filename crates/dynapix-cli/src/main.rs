//! `dynapix`: dynamic RGB-D visual SLAM (DynaPix, GCPR 2024) on the CPU.

#![forbid(unsafe_code)]

mod cmd;

use clap::{Parser, Subcommand};

/// Dynamic RGB-D visual SLAM with per-pixel motion probabilities (DynaPix) on the CPU.
#[derive(Parser)]
#[command(name = "dynapix", version, about, long_about = None)]
struct Cli {
    /// More log output (-v info, -vv debug).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// Hide progress bars (every command).
    #[arg(short, long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

// Parsed once per process, so the size difference between variants does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum Command {
    /// Evaluate trajectories: ATE, RPE, tracking rate, multi-run tables and plots.
    Eval(cmd::eval::Args),
    /// Dense optical flow between two images (DIS).
    Flow(cmd::flow::Args),
    /// Generate synthetic dynamic RGB-D sequences, or augment a real one with movers.
    Synth(cmd::synth::Args),
    /// Per-pixel motion probability maps for a sequence.
    Motion(cmd::motion::Args),
    /// Run SLAM on a sequence.
    Slam(cmd::slam::Args),
    /// Train or import a bag-of-words vocabulary.
    Vocab(cmd::vocab::Args),
    /// Run a method end to end on a sequence (offline: motion maps if needed, SLAM,
    /// evaluation; or online with --online).
    Run(cmd::run::Args),
    /// Run many methods × sequences × seeds and build the paper-style table.
    Experiment(cmd::experiment::Args),
    /// The one-command demo: synthetic walking sequences, ORB-SLAM2 vs DynaPix, report.
    Demo(cmd::demo::Args),
    /// Measure one run from scratch: time per stage, frames/s, CPU, memory, ATE.
    Bench(cmd::bench::Args),
}

fn main() -> std::process::ExitCode {
    // Before any thread starts: keep freed frame buffers for reuse instead of faulting their
    // pages in again for every frame (see the function's documentation).
    dynapix::bench::retain_freed_memory();
    let cli = Cli::parse();
    let level = match cli.verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    // The stage profiler only measures between start and stop (`dynapix bench`).
    let profiler = dynapix::bench::StageProfiler::new();
    {
        use tracing_subscriber::Layer;
        use tracing_subscriber::layer::SubscriberExt;
        use tracing_subscriber::util::SubscriberInitExt;
        tracing_subscriber::registry()
            .with(
                tracing_subscriber::fmt::layer()
                    .with_writer(std::io::stderr)
                    // Colour codes only for a terminal: a log file gets plain `WARN` lines.
                    .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
                    .with_filter(filter),
            )
            .with(profiler.layer())
            .init();
    }
    let bars = cmd::common::Bars::new(cli.quiet);
    let result = match cli.command {
        Command::Eval(a) => cmd::eval::run(a),
        Command::Flow(a) => cmd::flow::run(a),
        Command::Synth(a) => cmd::synth::run(a, &bars),
        Command::Motion(a) => cmd::motion::run(a, &bars),
        Command::Slam(a) => cmd::slam::run(a, &bars),
        Command::Vocab(a) => cmd::vocab::run(a, &bars),
        Command::Run(a) => cmd::run::run(a, &bars),
        Command::Experiment(a) => cmd::experiment::run(a, &bars),
        Command::Demo(a) => cmd::demo::run(a, &bars),
        Command::Bench(a) => cmd::bench::run(a, &bars, &profiler),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", cmd::common::report(&e));
            std::process::ExitCode::FAILURE
        }
    }
}
