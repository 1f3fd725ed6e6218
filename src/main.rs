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
    /// Print the control benchmark matrix (recycle-pi against baseline-pi) that README.md shows.
    BenchMatrix(cli::bench_matrix::BenchMatrixArgs),
    /// Run the controller service (SocketCAN / Modbus, or the in-process simulated plant).
    Run(cli::daemon::RunArgs),
    /// Run the simulated skid as a node on the field buses (hardware-in-the-loop).
    Plant(cli::daemon::PlantArgs),
    /// Check a configuration (the same checks as start-up and reload); exit status 78 (EX_CONFIG) on errors.
    CheckConfig(cli::daemon::CheckArgs),
    /// Print the event log readably.
    Events(cli::daemon::EventsArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Sim(args)) => cli::sim::run(&args),
        Some(Command::Table(args)) => cli::table::run(&args),
        Some(Command::BenchMatrix(args)) => cli::bench_matrix::run(&args),
        Some(Command::Run(args)) => cli::daemon::run(&args),
        Some(Command::Plant(args)) => cli::daemon::plant(&args),
        Some(Command::CheckConfig(args)) => match cli::daemon::check(&args) {
            Ok(code) => return code,
            Err(e) => Err(e),
        },
        Some(Command::Events(args)) => cli::daemon::events(&args),
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
                loop_delay_periods: 0,
                loop_delay_jitter_periods: 0,
            };
            cli::sim::run(&args)
        }
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            // a configuration error is not a crash: 78 (EX_CONFIG) stops systemd's restart loop
            if e.chain()
                .any(|c| c.is::<antisurge::config::ConfigInvalid>())
            {
                std::process::ExitCode::from(antisurge::config::EX_CONFIG)
            } else {
                std::process::ExitCode::from(2)
            }
        }
    }
}
