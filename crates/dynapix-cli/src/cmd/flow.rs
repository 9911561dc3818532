//! `dynapix flow` (being built).

/// Arguments of `dynapix flow`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `dynapix flow`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dynapix flow is not available in this build yet")
}
