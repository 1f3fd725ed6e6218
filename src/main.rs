//! The `antisurge` binary: the command-line edge over the library.

mod cli;

use std::io::Write as _;

use clap::{Parser, Subcommand};

/// antisurge: real-time anti-surge and active surge control for centrifugal compressors.
#[derive(Debug, Parser)]
#[command(
    name = "antisurge",
    version = concat!(env!("CARGO_PKG_VERSION"), " (commit ", env!("ANTISURGE_COMMIT"), ")"),
    about,
    long_about = None
)]
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
    /// Run the robustness campaign: random skids at field-bus loop rates, recycle-pi against
    /// baseline-pi and the feasibility oracle (`--case K` reruns one case).
    Campaign(cli::campaign::CampaignArgs),
    /// Run the controller service (SocketCAN / Modbus, or the in-process simulated plant).
    Run(cli::daemon::RunArgs),
    /// Run the simulated skid as a node on the field buses (hardware-in-the-loop).
    Plant(cli::daemon::PlantArgs),
    /// Check a configuration (the same checks as start-up and reload); exit status 78 (EX_CONFIG) on errors.
    CheckConfig(cli::daemon::CheckArgs),
    /// Reload the running controller (`systemctl reload` runs it): check the files against
    /// the running configuration, signal the daemon and wait for its answer; non-zero when
    /// it refused them (`--override` passes the valve-step dry run).
    Reload(cli::daemon::ReloadArgs),
    /// Print the event log readably.
    Events(cli::daemon::EventsArgs),
    /// Show the running controller's live status (mode, cause, deviation, valve, surges).
    Status(cli::status::StatusArgs),
    /// Operator action on the running controller (needs the operator token).
    Operate(cli::status::OperateArgs),
    /// Draw the map and time-series pictures of a trace.csv from `run`, `plant` or HIL.
    Plot(cli::plot::PlotArgs),
    /// Run the control core over a black-box recording (bit-exact with the recorded
    /// settings; with `--config`/`--law`, what another setting would have commanded).
    Replay(cli::replay::ReplayArgs),
    /// N simulated skids, each a Sparkplug B edge node, against one MQTT broker (a fleet
    /// benchmark: `.ci/sparkplug_fleet.sh` runs it with an independent host).
    FleetSim(cli::fleet::FleetArgs),
    /// Print shell completions (bash, zsh, fish, elvish, powershell) to stdout.
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
    /// Print the manual page (roff) to stdout: `antisurge man > antisurge.1`.
    Man,
}

fn main() -> std::process::ExitCode {
    // a panic repeated per request or per cycle must not flood the journal (issue 12)
    antisurge::runtime::panic_log::install(
        antisurge::runtime::panic_log::MAX_REPORTS_PER_WINDOW,
        antisurge::runtime::panic_log::REPORT_WINDOW,
    );
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Sim(args)) => cli::sim::run(&args),
        Some(Command::Table(args)) => cli::table::run(&args),
        Some(Command::BenchMatrix(args)) => cli::bench_matrix::run(&args),
        Some(Command::Campaign(args)) => cli::campaign::run(&args),
        Some(Command::Run(args)) => cli::daemon::run(&args),
        Some(Command::Plant(args)) => cli::daemon::plant(&args),
        Some(Command::CheckConfig(args)) => match cli::daemon::check(&args) {
            Ok(code) => return code,
            Err(e) => Err(e),
        },
        Some(Command::Reload(args)) => match cli::daemon::reload(&args) {
            Ok(code) => return code,
            Err(e) => Err(e),
        },
        Some(Command::Events(args)) => cli::daemon::events(&args),
        Some(Command::Status(args)) => cli::status::status(&args),
        Some(Command::Operate(args)) => cli::status::operate(&args),
        Some(Command::Plot(args)) => cli::plot::run(&args),
        Some(Command::Replay(args)) => match cli::replay::run(&args) {
            Ok(code) => return code,
            Err(e) => Err(e),
        },
        Some(Command::FleetSim(args)) => cli::fleet::run(&args),
        Some(Command::Completions { shell }) => {
            use clap::CommandFactory;
            clap_complete::generate(
                shell,
                &mut Cli::command(),
                "antisurge",
                &mut std::io::stdout(),
            );
            Ok(())
        }
        Some(Command::Man) => {
            use clap::CommandFactory;
            clap_mangen::Man::new(Cli::command())
                .render(&mut std::io::stdout())
                .map_err(anyhow::Error::from)
        }
        None => {
            // a bare `antisurge` explains itself instead of running anything
            use clap::CommandFactory;
            let _ = Cli::command().print_help();
            let _ = writeln!(std::io::stdout());
            return std::process::ExitCode::SUCCESS;
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
            } else if e.chain().any(|c| c.is::<antisurge::live::SurfaceError>()) {
                // an operator surface another process holds: 69 (EX_UNAVAILABLE)
                std::process::ExitCode::from(antisurge::live::EX_UNAVAILABLE)
            } else {
                std::process::ExitCode::from(2)
            }
        }
    }
}
