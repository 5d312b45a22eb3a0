//! `geostride ba --bal FILE`: bundle adjustment of a BAL problem, reported as Ceres reports it.

use std::path::PathBuf;

use anyhow::{Context, anyhow};

use super::bad_input;
use geostride::optim::RobustLoss;
use geostride::optim::ba::{BaSettings, LinearSolver};
use geostride::optim::bal::bundle_adjust;
use geostride::optim::bal::{bal_text, read_bal};

#[derive(clap::Args)]
pub struct Args {
    /// The problem in BAL format (Bundle Adjustment in the Large)
    #[arg(long, value_name = "FILE")]
    bal: PathBuf,
    /// Iteration limit
    #[arg(long, default_value = "50", value_name = "N")]
    max_iterations: usize,
    /// Loss on each observation: none, huber[:K] or cauchy[:K] (K in pixels)
    #[arg(long, default_value = "none", value_name = "LOSS")]
    loss: String,
    /// Reduced camera system: dense (Cholesky), iterative (conjugate gradients, Schur–Jacobi
    /// preconditioner) or auto (dense up to 200 cameras)
    #[arg(long, default_value = "auto", value_parser = ["auto", "dense", "iterative"])]
    linear_solver: String,
    /// The most memory the command may take, GB: the adjustment's is estimated before anything
    /// is allocated, and a problem that would need more is refused
    #[arg(long, default_value = "2", value_parser = super::parse_positive, value_name = "GB")]
    max_memory_gb: f64,
    /// Write the adjusted problem here (BAL)
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Print the summary and every iteration as JSON
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let loss: RobustLoss = args
        .loss
        .parse()
        .map_err(|e: String| bad_input(anyhow!("--loss: {e}")))?;
    if let Some(out) = &args.out {
        super::check_output_file(out, [&args.bal])?;
    }
    let mut problem = read_bal(&args.bal).map_err(bad_input)?;
    let summary = bundle_adjust(
        &mut problem,
        &BaSettings {
            max_iterations: args.max_iterations,
            loss,
            linear_solver: match args.linear_solver.as_str() {
                "dense" => LinearSolver::DenseSchur,
                "iterative" => LinearSolver::IterativeSchur,
                _ => LinearSolver::Auto,
            },
            // What the process holds already (the problem read) counts against the budget.
            max_memory_bytes: ((args.max_memory_gb * 1e9) as u64)
                .saturating_sub(geostride::io::resident_bytes().unwrap_or(0)),
            ..BaSettings::default()
        },
    )
    .map_err(|e| bad_input(anyhow!("{}: {e}", args.bal.display())))?;
    if let Some(out) = &args.out {
        geostride::io::write_atomic(out, bal_text(&problem).as_bytes())
            .with_context(|| out.display().to_string())?;
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok(());
    }
    println!(
        "{}: {} cameras, {} points, {} observations",
        args.bal.display(),
        summary.cameras,
        summary.points,
        summary.observations
    );
    println!(
        "iter      cost      cost_change  |gradient|   |step|    tr_ratio  tr_radius  accepted  iter_time"
    );
    println!("   0  {:.6e}", summary.initial_cost);
    for it in &summary.iterations {
        println!(
            "{:>4}  {:.6e}  {:>10.3e}  {:>10.3e}  {:>9.3e}  {:>8.3e}  {:>9.3e}  {:>8}  {:>8.3}s",
            it.iteration,
            it.cost,
            it.cost_change,
            it.gradient_max_norm,
            it.step_norm,
            it.rho,
            it.radius,
            if it.accepted { "yes" } else { "no" },
            it.seconds
        );
    }
    println!("initial cost    {:.6e}", summary.initial_cost);
    println!("final cost      {:.6e}", summary.final_cost);
    println!(
        "iterations      {} ({} accepted)",
        summary.iterations.len(),
        summary.accepted_steps
    );
    println!("time            {:.3} s", summary.seconds);
    println!("termination     {}", summary.termination);
    Ok(())
}
