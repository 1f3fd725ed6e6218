//! `antisurge status` and `antisurge operate`: ask the running daemon over its status socket.

use anyhow::{anyhow, Context, Result};
use clap::Args;
use std::path::PathBuf;

/// Arguments of `antisurge status`.
#[derive(Debug, Args)]
pub struct StatusArgs {
    /// Print the JSON report (machine-readable) instead of the text.
    #[arg(long)]
    pub json: bool,
    /// The daemon's status socket (default: /run/antisurge/status.sock if it exists, else
    /// ./out/status.sock).
    #[arg(long)]
    pub socket: Option<PathBuf>,
    /// The report of the snapshot of this control cycle, as served recently to the web HMI
    /// (its page shows the cycle) or to a status client, instead of the latest one.
    #[arg(long, value_name = "N")]
    pub cycle: Option<u64>,
}

/// Arguments of `antisurge operate`.
#[derive(Debug, Args)]
pub struct OperateArgs {
    /// File holding the operator token (default /etc/antisurge/operator.token).
    #[arg(long, default_value = "/etc/antisurge/operator.token")]
    pub token_file: PathBuf,
    /// The daemon's status socket (as for `antisurge status`).
    #[arg(long)]
    pub socket: Option<PathBuf>,
    /// The action: `auto`, `manual [PCT]`, `output PCT`, `reset-surge-counter`, `ack`.
    #[arg(required = true, num_args = 1..)]
    pub action: Vec<String>,
}

fn socket(p: &Option<PathBuf>) -> PathBuf {
    p.clone()
        .or_else(|| std::env::var_os("ANTISURGE_STATUS__SOCKET").map(PathBuf::from))
        .unwrap_or_else(antisurge::live::default_client_socket)
}

fn ask(sock: &std::path::Path, line: &str) -> Result<serde_json::Value> {
    antisurge::live::server::request(sock, line).with_context(|| {
        format!(
            "no answer on {} (is the daemon running? `systemctl status antisurge`; \
             another socket: --socket)",
            sock.display()
        )
    })
}

/// Print the daemon's status.
pub fn status(args: &StatusArgs) -> Result<()> {
    let sock = socket(&args.socket);
    let request = match args.cycle {
        Some(c) => format!("status {c}"),
        None => "status".into(),
    };
    let v = ask(&sock, &request)?;
    if let Some(e) = v.get("error") {
        return Err(anyhow!(
            "the daemon says: {}",
            e.as_str().unwrap_or_default()
        ));
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let r: antisurge::live::report::StatusReport =
        serde_json::from_value(v).context("unexpected status reply")?;
    print!("{}", antisurge::live::report::human(&r));
    Ok(())
}

/// Send an operator action.
pub fn operate(args: &OperateArgs) -> Result<()> {
    let token = std::fs::read_to_string(&args.token_file).with_context(|| {
        format!(
            "cannot read the operator token {}",
            args.token_file.display()
        )
    })?;
    let token = token.lines().next().unwrap_or("").trim().to_string();
    let sock = socket(&args.socket);
    let v = ask(&sock, &format!("op {token} {}", args.action.join(" ")))?;
    match (v.get("ok"), v.get("error")) {
        (Some(ok), _) => {
            println!("{}", ok.as_str().unwrap_or_default());
            Ok(())
        }
        (_, Some(e)) => Err(anyhow!("refused: {}", e.as_str().unwrap_or_default())),
        _ => Err(anyhow!("unexpected reply {v}")),
    }
}
