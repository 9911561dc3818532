//! `dynapix demo` (being built).

/// Arguments of `dynapix demo`.
#[derive(clap::Args)]
pub struct Args {}

/// Runs `dynapix demo`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dynapix demo is not available in this build yet")
}
