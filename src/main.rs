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

/// The commands, in the order `antisurge --help` lists them (`display_order`): the operator's
/// first (the controller service, its status, actions, events, config check and reload, the
/// simulator), then the engineer's tools (the simulated skid, replay, pictures, shell
/// completions, manual pages), then the developer's benchmarks.
#[derive(Debug, Subcommand)]
enum Command {
    // ---- operator
    /// Run the controller service (SocketCAN / Modbus, or the in-process simulated plant).
    #[command(display_order = 1)]
    Run(cli::daemon::RunArgs),
    /// Show the running controller's live status (mode, cause, deviation, valve, surges).
    #[command(display_order = 2)]
    Status(cli::status::StatusArgs),
    /// Operator action on the running controller (needs the operator token).
    #[command(display_order = 3)]
    Operate(cli::status::OperateArgs),
    /// Print the event log readably.
    #[command(display_order = 4)]
    Events(cli::daemon::EventsArgs),
    /// Check a configuration (the same checks as start-up and reload); exit status 78 (EX_CONFIG) on errors.
    #[command(display_order = 5)]
    CheckConfig(cli::daemon::CheckArgs),
    /// Reload the running controller (`systemctl reload` runs it): check the files against
    /// the running configuration, signal the daemon and wait for its answer; non-zero when
    /// it refused them (`--override` passes the valve-step dry run).
    #[command(display_order = 6)]
    Reload(cli::daemon::ReloadArgs),
    /// Simulate a scenario on a benchmark plant (no hardware needed).
    #[command(display_order = 7)]
    Sim(cli::sim::SimArgs),
    // ---- engineer
    /// Run the simulated skid as a node on the field buses (hardware-in-the-loop).
    #[command(display_order = 20)]
    Plant(cli::daemon::PlantArgs),
    /// Run the control core over a black-box recording (bit-exact with the recorded
    /// settings; with `--config`/`--law`, what another setting would have commanded).
    #[command(display_order = 21)]
    Replay(cli::replay::ReplayArgs),
    /// Draw the map and time-series pictures of a trace.csv from `run`, `plant` or HIL.
    #[command(display_order = 22)]
    Plot(cli::plot::PlotArgs),
    /// Print shell completions (bash, zsh, fish, elvish, powershell) to stdout.
    #[command(display_order = 23)]
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
    /// Print the manual page (roff) to stdout (`antisurge man > antisurge.1`), or write one
    /// page per command into a directory (`--out DIR`).
    #[command(display_order = 24)]
    Man(cli::man::ManArgs),
    // ---- developer: benchmarks
    /// Print the benchmark table (every plant × applicable law) that docs/benchmarks.md shows.
    #[command(display_order = 40)]
    Table(cli::table::TableArgs),
    /// Print the control benchmark matrix (recycle-pi against baseline-pi) that docs/benchmarks.md shows.
    #[command(display_order = 41)]
    BenchMatrix(cli::bench_matrix::BenchMatrixArgs),
    /// Run the robustness campaign: random skids at field-bus loop rates, recycle-pi against
    /// baseline-pi and the feasibility oracle (`--case K` reruns one case).
    #[command(display_order = 42)]
    Campaign(cli::campaign::CampaignArgs),
    /// N simulated skids, each a Sparkplug B edge node, against one MQTT broker (a fleet
    /// benchmark: `.ci/sparkplug_fleet.sh` runs it with an independent host).
    #[command(display_order = 43)]
    FleetSim(cli::fleet::FleetArgs),
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
        Some(Command::Man(args)) => {
            use clap::CommandFactory;
            cli::man::run(Cli::command(), &args)
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
