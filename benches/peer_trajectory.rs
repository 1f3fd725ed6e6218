//! Rust side of the peer comparison with scipy (`benches/peer_scipy.py` drives it).
//!
//! Problem: a recycle plant (default `kvangardsnes2009_recycle`) in open loop. It starts at its
//! initial steady state; the drive torque is held at the initial load torque, the recycle valve
//! and the feed are held, and the throttle *command* steps from its initial opening (60 %) to
//! 20 % at `t_step` (1 s), so the inputs are piecewise constant. The 9-state ODE
//! (`RecyclePlant as OdeSystem<9>`) is integrated over [0, t_end] with output on a fixed grid.
//! Both segments are integrated separately (restart at the discontinuity), as the Python side
//! does with `solve_ivp`.
//!
//! For every method and rtol it times only the integration loop (median of `--repeats`), and
//! writes to `--out-dir`:
//! - `problem.json`: the fitted map coefficients, x0, held inputs, grid, per-component scales
//!   (atol = rtol · scale), RHS values at self-check states, and one entry per run (wall times,
//!   step statistics, trajectory file name);
//! - `<run>.f64`: the trajectory, row-major (n_out × 9) little-endian f64.
//!
//! Problem B restarts from the reference's state at `--restart-at` (3 s, in deep surge) with
//! the same held inputs and runs to `t_end`: see `benches/README.md` for why.
//!
//! Without `--bench` (which `cargo bench` passes) the defaults shrink to a smoke run (2.5 s,
//! rtol 1e-4, one repeat, output in `target/peer_scipy_smoke/`), so that
//! `cargo test --all-targets` stays quick.
//!
//! Run: `cargo bench --bench peer_trajectory -- [--out-dir DIR] [--plant FILE] [--t-end S]
//! [--t-step S] [--dt-out S] [--rtols 1e-4,1e-6] [--ref-rtol 1e-10] [--repeats N]
//! [--restart-at S]`.

use antisurge::physics::compressor_map::{FlowCoordinate, MapModel};
use antisurge::plant::recycle_system::{ix, RecyclePlant, N};
use antisurge::plant::{PlantInputs, SimPlant};
use antisurge::sim::case::PlantCase;
use antisurge::solver::{dormand_prince, rosenbrock, AdaptiveStats, OdeSystem, Tolerance};
use nalgebra::SVector;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::Instant;

struct Args {
    out_dir: PathBuf,
    plant: PathBuf,
    t_end: f64,
    t_step: f64,
    throttle_after: f64,
    dt_out: f64,
    rtols: Vec<f64>,
    ref_rtol: f64,
    repeats: usize,
    restart_at: f64,
}

fn parse_args() -> Result<Args, String> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut a = Args {
        out_dir: root.join("target/peer_scipy"),
        plant: root.join("config/plants/kvangardsnes2009_recycle.toml"),
        t_end: 8.0,
        t_step: 1.0,
        throttle_after: 0.2,
        dt_out: 1e-3,
        rtols: vec![1e-4, 1e-5, 1e-6, 1e-7, 1e-8],
        ref_rtol: 1e-10,
        repeats: 5,
        restart_at: 3.0,
    };
    // `cargo bench` passes --bench; without it (`cargo test --all-targets`, or the binary run
    // by hand without arguments) run a quick smoke version unless arguments say otherwise
    let argv: Vec<String> = std::env::args().skip(1).collect();
    if !argv.iter().any(|a| a == "--bench") {
        a.out_dir = root.join("target/peer_scipy_smoke");
        a.t_end = 2.5;
        a.rtols = vec![1e-4];
        a.repeats = 1;
    }
    let mut it = argv.into_iter();
    let num = |s: Option<String>, name: &str| -> Result<f64, String> {
        s.ok_or(format!("{name} needs a value"))?
            .parse::<f64>()
            .map_err(|e| format!("{name}: {e}"))
    };
    while let Some(arg) = it.next() {
        match arg.as_str() {
            // cargo bench passes --bench to every bench target
            "--bench" => {}
            "--out-dir" => a.out_dir = PathBuf::from(it.next().ok_or("--out-dir needs a path")?),
            "--plant" => a.plant = PathBuf::from(it.next().ok_or("--plant needs a path")?),
            "--t-end" => a.t_end = num(it.next(), "--t-end")?,
            "--t-step" => a.t_step = num(it.next(), "--t-step")?,
            "--throttle-after" => a.throttle_after = num(it.next(), "--throttle-after")?,
            "--dt-out" => a.dt_out = num(it.next(), "--dt-out")?,
            "--restart-at" => a.restart_at = num(it.next(), "--restart-at")?,
            "--ref-rtol" => a.ref_rtol = num(it.next(), "--ref-rtol")?,
            "--repeats" => a.repeats = num(it.next(), "--repeats")?.max(1.0) as usize,
            "--rtols" => {
                a.rtols = it
                    .next()
                    .ok_or("--rtols needs a list")?
                    .split(',')
                    .map(|s| s.trim().parse::<f64>().map_err(|e| format!("--rtols: {e}")))
                    .collect::<Result<_, _>>()?
            }
            "-h" | "--help" => {
                println!("see the header of benches/peer_trajectory.rs");
                std::process::exit(0);
            }
            other => return Err(format!("unknown argument `{other}`")),
        }
    }
    Ok(a)
}

/// The open-loop problem: the plant with its held inputs before and after the step.
struct Problem {
    plant: RecyclePlant,
    x0: SVector<f64, N>,
    torque_nm: f64,
    recycle: f64,
    feed: f64,
    throttle_before: f64,
    throttle_after: f64,
    /// Output grid.
    grid: Vec<f64>,
    /// Index of the grid point at which the throttle command steps.
    k_step: usize,
    /// Typical magnitude per state (atol = rtol · scale).
    scale: [f64; N],
}

impl Problem {
    fn new(desc: &PlantCase, a: &Args) -> Problem {
        let init = desc.file.initial;
        let inputs = PlantInputs {
            throttle_process: init.throttle,
            recycle_manual: init.recycle_valve,
            feed: init.feed,
            ..PlantInputs::default()
        };
        let plant = match SimPlant::new(desc, &inputs) {
            Ok(SimPlant::Recycle(p)) => p,
            Ok(_) => panic!("{}: not a recycle_system plant", desc.path.display()),
            Err(e) => panic!("{e}"),
        };
        let x0 = plant.x;
        let torque_nm = plant.shaft.load_torque_nm(x0[ix::WC], x0[ix::OMEGA]);
        let n_out = (a.t_end / a.dt_out).round() as usize + 1;
        let grid: Vec<f64> = (0..n_out).map(|k| k as f64 * a.dt_out).collect();
        let k_step = (a.t_step / a.dt_out).round() as usize;
        assert!(
            k_step > 0 && k_step < n_out - 1,
            "t_step must lie inside the grid"
        );
        let p_scale = x0[ix::P1].abs().max(x0[ix::P2].abs());
        let w_scale = x0[ix::WC].abs();
        let scale = [
            p_scale,
            p_scale,
            w_scale,
            w_scale,
            w_scale,
            x0[ix::OMEGA].abs(),
            1.0,
            1.0,
            1.0,
        ];
        Problem {
            plant,
            x0,
            torque_nm,
            recycle: init.recycle_valve,
            feed: init.feed,
            throttle_before: init.throttle,
            throttle_after: a.throttle_after,
            grid,
            k_step,
            scale,
        }
    }

    fn system(&self, throttle: f64) -> RecyclePlant {
        let mut p = self.plant.clone();
        p.hold_inputs(self.torque_nm, self.recycle, throttle, self.feed);
        p
    }

    fn tolerance(&self, rtol: f64) -> Tolerance<N> {
        let mut atol = [0.0; N];
        for (a, s) in atol.iter_mut().zip(self.scale) {
            *a = rtol * s;
        }
        Tolerance { rtol, atol }
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Method {
    Ros2,
    Dp45,
}

impl Method {
    fn name(self) -> &'static str {
        match self {
            Method::Ros2 => "ros2",
            Method::Dp45 => "dp45",
        }
    }
}

/// Integrate from grid point `k0` (state `x_start`) to the end of the grid into `out`
/// (preallocated, one row per grid point from `k0` on).
#[allow(clippy::too_many_arguments)]
fn integrate(
    prob: &Problem,
    before: &RecyclePlant,
    after: &RecyclePlant,
    method: Method,
    tol: &Tolerance<N>,
    k0: usize,
    x_start: &SVector<f64, N>,
    out: &mut [[f64; N]],
) -> AdaptiveStats {
    let mut stats = AdaptiveStats::default();
    let mut x = *x_start;
    out[0].copy_from_slice(x.as_slice());
    // initial step guess, reset at the discontinuity (solve_ivp restarts there too)
    let h0 = 1e-5;
    let mut h = h0;
    let g = &prob.grid;
    for k in k0..g.len() - 1 {
        if k == prob.k_step {
            h = h0;
        }
        let sys = if k < prob.k_step { before } else { after };
        match method {
            Method::Ros2 => {
                rosenbrock::integrate(sys, g[k], &mut x, g[k + 1], tol, &mut h, &mut stats)
            }
            Method::Dp45 => {
                dormand_prince::integrate(sys, g[k], &mut x, g[k + 1], tol, &mut h, &mut stats)
            }
        }
        out[k + 1 - k0].copy_from_slice(x.as_slice());
    }
    stats
}

struct Run {
    label: String,
    method: Method,
    rtol: f64,
    walls: Vec<f64>,
    stats: AdaptiveStats,
    traj: Vec<[f64; N]>,
}

/// Time `repeats` integrations from grid point `k0` with state `x_start`.
fn run(
    prob: &Problem,
    (k0, x_start): (usize, &SVector<f64, N>),
    method: Method,
    rtol: f64,
    repeats: usize,
    label: &str,
) -> Run {
    let before = prob.system(prob.throttle_before);
    let after = prob.system(prob.throttle_after);
    let tol = prob.tolerance(rtol);
    let mut traj = vec![[0.0; N]; prob.grid.len() - k0];
    let mut walls = Vec::with_capacity(repeats);
    let mut stats = AdaptiveStats::default();
    for _ in 0..repeats {
        let t = Instant::now();
        stats = integrate(prob, &before, &after, method, &tol, k0, x_start, &mut traj);
        walls.push(t.elapsed().as_secs_f64());
        std::hint::black_box(&traj);
    }
    Run {
        label: label.to_string(),
        method,
        rtol,
        walls,
        stats,
        traj,
    }
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// States at which both RHS implementations are compared: the initial state, hand-made states
/// that reach every branch (reverse compressor and recycle flow, closed check valve, flow and
/// speed beyond the fitted map, rate-limited and lagging positioners), pseudo-random states
/// around x0, and states along the reference trajectory (deep surge).
fn selfcheck_states(prob: &Problem, reference: &[[f64; N]]) -> Vec<SVector<f64, N>> {
    let x0 = prob.x0;
    let pa = prob.plant.downstream_pa();
    let mut v = vec![x0];
    let mut with = |edits: &[(usize, f64)]| {
        let mut x = x0;
        for &(i, val) in edits {
            x[i] = val;
        }
        v.push(x);
    };
    let (p1, p2, wc) = (x0[ix::P1], x0[ix::P2], x0[ix::WC]);
    with(&[(ix::WC, -0.3 * wc)]); // reverse compressor flow
    with(&[(ix::WC, -1.5 * wc)]); // far reverse: linear continuation below flow_lo
    with(&[(ix::WC, 4.0 * wc)]); // beyond flow_hi
    with(&[(ix::WR, -0.2 * wc), (ix::P2, 0.9 * p1)]); // reverse recycle flow, p2 < p1
    with(&[(ix::WT, 0.0), (ix::P2, 0.98 * pa)]); // check valve shut, closing Δp
    with(&[(ix::WT, -1e-4), (ix::P2, 0.95 * pa)]); // slightly negative (unprojected) flow
    with(&[(ix::WT, 0.0), (ix::P2, 1.05 * pa)]); // check valve opening
    with(&[(ix::OMEGA, 0.4 * x0[ix::OMEGA])]); // below the map's speed range: fan laws
    with(&[(ix::OMEGA, 1.6 * x0[ix::OMEGA])]); // above the map's speed range
    with(&[(ix::LT, 0.9), (ix::LR, 0.01), (ix::LF, 0.5)]); // positioners rate-limited
    with(&[(ix::LT, 0.201), (ix::LR, 0.1199), (ix::LF, 0.999)]); // positioners in their lag
    with(&[(ix::P1, 0.5 * p1), (ix::P2, 1.2 * p2), (ix::WC, 0.5 * wc)]);
    // pseudo-random states around x0 (xorshift, fixed seed)
    let mut s: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut rnd = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    for _ in 0..20 {
        let mut x = x0;
        x[ix::P1] *= 1.0 + 0.4 * rnd();
        x[ix::P2] *= 1.0 + 0.3 * rnd();
        x[ix::WC] *= 1.0 + 1.5 * rnd();
        x[ix::WR] = x0[ix::WR] * (1.0 + 2.0 * rnd());
        x[ix::WT] = (x0[ix::WT] * (1.0 + 1.5 * rnd())).max(0.0);
        x[ix::OMEGA] *= 1.0 + 0.5 * rnd();
        x[ix::LR] = 0.5 + 0.5 * rnd();
        x[ix::LT] = 0.5 + 0.5 * rnd();
        x[ix::LF] = 1.0 + 0.3 * rnd();
        v.push(x);
    }
    // along the reference trajectory, every 50 ms
    let every = ((0.05 / (prob.grid[1] - prob.grid[0])).round() as usize).max(1);
    for row in reference.iter().step_by(every) {
        v.push(SVector::<f64, N>::from_column_slice(row));
    }
    v
}

fn write_traj(path: &Path, traj: &[[f64; N]]) -> std::io::Result<()> {
    let mut bytes = Vec::with_capacity(traj.len() * N * 8);
    for row in traj {
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(path, bytes)
}

fn main() {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("peer_trajectory: {e}");
            std::process::exit(2);
        }
    };
    let desc = PlantCase::load(&args.plant).unwrap_or_else(|e| panic!("{e}"));
    let prob = Problem::new(&desc, &args);
    std::fs::create_dir_all(&args.out_dir).expect("create output directory");

    let map = match desc.map.model {
        MapModel::Polynomial(m) => json!({
            "kind": "polynomial",
            "coeffs": m.coeffs,
            "flow_scale": m.flow_scale,
            "omega_center": m.omega_center,
            "omega_scale": m.omega_scale,
            "omega_min": m.omega_min,
            "omega_max": m.omega_max,
            "flow_lo": m.flow_lo,
            "flow_hi": m.flow_hi,
        }),
        MapModel::Cubic(_) => panic!("the Python side implements the fitted polynomial map only"),
    };
    let flow_coordinate = match desc.map.flow_coordinate {
        FlowCoordinate::MassKgS => "mass_kg_s",
        FlowCoordinate::InletVolumeM3S => "inlet_volume_m3_s",
    };

    eprintln!(
        "peer_trajectory: {} open loop, throttle {} -> {} at {} s, {} s, output every {} s, {} repeats",
        desc.name(),
        prob.throttle_before,
        prob.throttle_after,
        args.t_step,
        args.t_end,
        args.dt_out,
        args.repeats
    );

    // Problem A, the scenario: reference first (it also supplies self-check states and the
    // restart state of problem B), a check of the reference at a 10x tighter tolerance, then
    // the sweep. Problem B: the same from the reference's state at `--restart-at` (deep
    // surge) to the end, a well-conditioned IVP for pointwise accuracy through surge cycles
    // (the onset of surge in A is not: see benches/README.md).
    let start_a = (0, &prob.x0);
    let mut runs = vec![
        run(&prob, start_a, Method::Dp45, args.ref_rtol, 1, "reference"),
        run(
            &prob,
            start_a,
            Method::Dp45,
            args.ref_rtol * 0.1,
            1,
            "reference_check",
        ),
    ];
    let k_b =
        ((args.restart_at / args.dt_out).round() as usize).clamp(prob.k_step, prob.grid.len() - 2);
    let x_b = SVector::<f64, N>::from_column_slice(&runs[0].traj[k_b]);
    let start_b = (k_b, &x_b);
    runs.push(run(
        &prob,
        start_b,
        Method::Dp45,
        args.ref_rtol,
        1,
        "b_reference",
    ));
    runs.push(run(
        &prob,
        start_b,
        Method::Dp45,
        args.ref_rtol * 0.1,
        1,
        "b_reference_check",
    ));
    for &rtol in &args.rtols {
        for method in [Method::Ros2, Method::Dp45] {
            let label = format!("{}_{rtol:e}", method.name());
            runs.push(run(&prob, start_a, method, rtol, args.repeats, &label));
            let label = format!("b_{}_{rtol:e}", method.name());
            runs.push(run(&prob, start_b, method, rtol, args.repeats, &label));
        }
    }

    let before = prob.system(prob.throttle_before);
    let after = prob.system(prob.throttle_after);
    let selfcheck: Vec<Value> = selfcheck_states(&prob, &runs[0].traj)
        .iter()
        .flat_map(|x| {
            [
                (&before, prob.throttle_before),
                (&after, prob.throttle_after),
            ]
            .map(|(sys, th)| {
                json!({
                    "throttle_cmd": th,
                    "x": x.as_slice(),
                    "f": sys.rhs(0.0, x).as_slice(),
                })
            })
        })
        .collect();

    let mut run_json = Vec::new();
    for r in &runs {
        let file = format!("{}.f64", r.label);
        write_traj(&args.out_dir.join(&file), &r.traj).expect("write trajectory");
        let wall = median(&r.walls);
        eprintln!(
            "  {:<16} {} rtol {:>7.0e}: median {:>9.3} ms  ({} accepted, {} rejected, {} RHS evaluations)",
            r.label,
            r.method.name(),
            r.rtol,
            wall * 1e3,
            r.stats.accepted,
            r.stats.rejected,
            r.stats.rhs_evals
        );
        run_json.push(json!({
            "label": r.label,
            "method": r.method.name(),
            "rtol": r.rtol,
            "atol": prob.tolerance(r.rtol).atol,
            "wall_s": wall,
            "walls_s": r.walls,
            "accepted": r.stats.accepted,
            "rejected": r.stats.rejected,
            "rhs_evals": r.stats.rhs_evals,
            "problem": if r.label.starts_with("b_") { "B" } else { "A" },
            "file": file,
        }));
    }

    let doc = json!({
        "plant_file": desc.path.canonicalize().unwrap_or(desc.path.clone()),
        "plant": desc.name(),
        "map": map,
        "flow_coordinate": flow_coordinate,
        "x0": prob.x0.as_slice(),
        "torque_nm": prob.torque_nm,
        "recycle": prob.recycle,
        "feed": prob.feed,
        "downstream_scale": 1.0,
        "throttle_before": prob.throttle_before,
        "throttle_after": prob.throttle_after,
        "t_step": prob.grid[prob.k_step],
        "t_end": prob.grid[prob.grid.len() - 1],
        "dt_out": args.dt_out,
        "n_out": prob.grid.len(),
        "k_restart": k_b,
        "t_restart": prob.grid[k_b],
        "scale": prob.scale,
        "selfcheck": selfcheck,
        "runs": run_json,
    });
    let path = args.out_dir.join("problem.json");
    std::fs::write(&path, serde_json::to_string_pretty(&doc).expect("json")).expect("write json");
    eprintln!("peer_trajectory: wrote {}", path.display());
}
