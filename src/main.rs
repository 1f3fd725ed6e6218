//! The `antisurge` binary: the command-line edge over the library.

mod cli;

use clap::{Parser, Subcommand};

/// antisurge: real-time anti-surge and active surge control for centrifugal compressors.
#[derive(Debug, Parser)]
#[command(name = "antisurge", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Simulate a scenario on a benchmark plant (no hardware needed).
    Sim(cli::sim::SimArgs),
    /// Print the benchmark table (every plant × applicable law) that README.md shows.
    Table(cli::table::TableArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Sim(args)) => cli::sim::run(&args),
        Some(Command::Table(args)) => cli::table::run(&args),
        None => {
            // a bare `antisurge` runs the default simulation
            let args = cli::sim::SimArgs {
                plant: cli::sim::DEFAULT_PLANT.into(),
                scenario: cli::sim::DEFAULT_SCENARIO.into(),
                law: cli::sim::DEFAULT_LAW.into(),
                out: None,
                config_dir: None,
                no_plots: false,
                json: false,
            };
            cli::sim::run(&args)
        }
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::from(2)
        }
    }
}
