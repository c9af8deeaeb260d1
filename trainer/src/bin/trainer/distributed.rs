//! `trainer train --distributed` and the hidden `trainer distributed-point-mass`: MPI set-up,
//! flags to [`DistributedConfig`], one line of counters per rank at the end (docs/distributed.md).

use std::time::Duration;

use clap::Args;

use dex_trainer::learn::distributed::DistributedConfig;

#[cfg(not(feature = "mpi"))]
use crate::TrainArgs;

/// `trainer distributed-point-mass` flags.
#[derive(Args, Debug)]
pub(crate) struct PointMassArgs {
    /// Transitions of the whole run (all ranks).
    #[arg(long, default_value_t = 6_000)]
    transitions: u64,
    /// Worker threads per worker rank.
    #[arg(short = 'W', long, default_value_t = 1)]
    workers: usize,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Evaluation episodes of the final actor (rank 0).
    #[arg(long, default_value_t = 100)]
    eval_episodes: usize,
    /// A worker rank exchanges after this many of its updates.
    #[arg(long)]
    exchange_every: Option<u64>,
    /// Seconds after which a silent worker rank is lost.
    #[arg(long)]
    rank_timeout: Option<f64>,
}

fn config(
    exchange_every: Option<u64>,
    rank_timeout: Option<f64>,
    respawn_after: Option<f64>,
) -> anyhow::Result<DistributedConfig> {
    let mut c = DistributedConfig::default();
    if let Some(k) = exchange_every {
        c.exchange_every = k;
    }
    if let Some(t) = rank_timeout {
        c.rank_timeout = Duration::try_from_secs_f64(t)
            .map_err(|_| anyhow::anyhow!("--rank-timeout must be a number of seconds"))?;
    }
    if let Some(t) = respawn_after {
        c.respawn_after = Some(
            Duration::try_from_secs_f64(t)
                .map_err(|_| anyhow::anyhow!("--respawn-after must be a number of seconds"))?,
        );
    }
    c.validate()?;
    Ok(c)
}

#[cfg(not(feature = "mpi"))]
fn no_mpi() -> anyhow::Result<()> {
    anyhow::bail!(
        "this trainer was built without MPI: build it with `cargo build --release -p dex-trainer \
         --features mpi` (needs libopenmpi-dev and libclang-dev; docs/distributed.md)"
    )
}

/// `trainer train --distributed`.
#[cfg(not(feature = "mpi"))]
pub(crate) fn train(a: &TrainArgs) -> anyhow::Result<()> {
    config(a.exchange_every, a.rank_timeout, a.respawn_after)?;
    no_mpi()
}

/// `trainer distributed-point-mass`.
#[cfg(not(feature = "mpi"))]
pub(crate) fn point_mass(a: &PointMassArgs) -> anyhow::Result<()> {
    config(a.exchange_every, a.rank_timeout, None)?;
    no_mpi()
}

#[cfg(feature = "mpi")]
pub(crate) use with_mpi::{point_mass, train};

#[cfg(feature = "mpi")]
mod with_mpi {
    use super::{DistributedConfig, PointMassArgs, config};
    use crate::TrainArgs;
    use crate::train::{Terminal, apply_flags, load_scene, stop_flag};
    use dex_trainer::learn::Progress;
    use dex_trainer::learn::distributed::mpi_transport::MpiTransport;
    use dex_trainer::learn::distributed::point_mass::{point_mass_config, run_point_mass};
    use dex_trainer::learn::distributed::server::Server;
    use dex_trainer::learn::distributed::{ExchangeStats, Transport};
    use dex_trainer::pipeline::train_run::TrainPlan;
    use dex_trainer::pipeline::train_settings;
    use std::time::Instant;

    /// Exit code of rank 0 after a failed distributed run (passed to `MPI_Abort`).
    const FAILED: i32 = 3;

    /// Writes `line` and a newline to stderr in one `write` call. `eprintln!` writes each piece of
    /// its format on its own (stderr is unbuffered), so under `mpirun`, which forwards every rank's
    /// output as it comes, two ranks' lines could interleave mid-line; one write of less than
    /// `PIPE_BUF` bytes to a pipe arrives whole.
    fn line_to_stderr(line: &str) {
        use std::io::Write;
        let mut bytes = Vec::with_capacity(line.len() + 1);
        bytes.extend_from_slice(line.as_bytes());
        bytes.push(b'\n');
        // Nothing sensible is left to do when stderr is gone.
        let _ = std::io::stderr().lock().write_all(&bytes);
    }

    /// One line of a rank's counters (stderr: rank 0's stdout is the run's output).
    fn report(rank: usize, wall_s: f64, p: &Progress, st: &ExchangeStats) {
        line_to_stderr(&format!(
            "rank {rank}: {} transitions ({:.1}/s), {} updates ({:.1}/s) in {wall_s:.1} s; \
             {} exchanges, {} refused, {} late answers adopted, {:.0} bytes sent and {:.0} \
             received per exchange, latency mean {:.2} ms max {:.2} ms",
            p.transitions,
            p.transitions as f64 / wall_s.max(1e-9),
            p.updates,
            p.updates as f64 / wall_s.max(1e-9),
            st.exchanges,
            st.refused,
            st.readmitted,
            st.bytes_sent as f64 / st.exchanges.max(1) as f64,
            st.bytes_received as f64 / st.exchanges.max(1) as f64,
            st.mean_latency_s() * 1e3,
            st.latency_max_s * 1e3,
        ));
    }

    pub(crate) fn train(a: &TrainArgs) -> anyhow::Result<()> {
        let cfg = config(a.exchange_every, a.rank_timeout, a.respawn_after)?;
        let mut transport = MpiTransport::init()?;
        let result = train_with(a, cfg, &mut transport);
        if let Err(e) = &result
            && transport.is_replacement()
        {
            line_to_stderr(&format!("error: rank {}: {e:#}", transport.rank()));
            // A replacement that failed must not disconnect from rank 0 (dropping the transport
            // would: it waits for rank 0, and an MPI_Abort while it waits hung mpirun in the
            // spike): it exits without finalising MPI, as a dead rank does, and rank 0 loses it.
            std::process::exit(FAILED);
        }
        result
    }

    fn train_with(
        a: &TrainArgs,
        cfg: DistributedConfig,
        transport: &mut MpiTransport,
    ) -> anyhow::Result<()> {
        let stop = stop_flag()?;
        let mut s = train_settings::load(a.config.as_deref())?;
        apply_flags(&mut s, a);
        let plan = TrainPlan::new(s)?;
        let scene = load_scene()?;
        let rank = transport.rank();
        if transport.size() == 1 {
            // One rank: today's ADPG-R on local threads.
            let mut terminal = Terminal::new(a.quiet);
            plan.train(&scene, a.resume, &stop, &mut |ev| terminal.show(ev))?;
            return Ok(());
        }
        let t0 = Instant::now();
        if rank == 0 {
            let mut terminal = Terminal::new(a.quiet);
            let (result, stats, lost) = {
                // Each lost or re-admitted worker rank as it happens, one write per line.
                let mut server = Server::new(&mut *transport, cfg)?
                    .on_rank_change(|c| line_to_stderr(&format!("rank 0: {c}")));
                let r = plan.train_distributed(
                    &scene,
                    a.resume,
                    &stop,
                    &mut |ev| terminal.show(ev),
                    &mut server,
                );
                (r, server.stats(), server.membership().lost_now())
            };
            line_to_stderr(&format!(
                "rank 0: {} exchanges applied, {} messages refused, {} bytes sent, {} received in {:.1} s",
                stats.exchanges,
                stats.refused,
                stats.bytes_sent,
                stats.bytes_received,
                t0.elapsed().as_secs_f64()
            ));
            if let Err(e) = result {
                // One write: mpirun's abort banner, printed by another process into the same
                // stream, must not land inside the line (it did, 1 run in 12: session 13).
                line_to_stderr(&format!("error: {:#}", anyhow::Error::from(e)));
                // The other ranks would wait for rank 0 forever: end the job.
                transport.abort(FAILED);
            }
            if stats.replaced > 0 {
                // Replacements disconnect from rank 0 once they took the stop; an MPI_Abort while
                // one waits in its disconnect left mpirun hanging (measured), so rank 0 disconnects
                // from each present one first (a lost one is left alone: it would wait for ever).
                transport.disconnect_replacements(&lost);
            }
            if !lost.is_empty() || stats.replaced > 0 {
                // The run is complete and written. A rank still lost may be stopped or cut off
                // (it would hold MPI_Finalize, and mpirun, for ever) or dead (under
                // `orte_abort_on_non_zero_status 0` mpirun then never ends either): end the job.
                // mpirun exits 0 for a stopped rank, 137 when one was killed.
                let state = match (lost.is_empty(), stats.replaced) {
                    (false, 0) => format!("worker ranks {lost:?} are still lost"),
                    (false, n) => format!(
                        "worker ranks {lost:?} are still lost, {n} replacement ranks were started"
                    ),
                    (true, n) => {
                        format!("no worker rank is lost, {n} replacement ranks were started")
                    }
                };
                line_to_stderr(&format!(
                    "rank 0: the run is complete; {state}: ending the job (MPI_Abort with code 0)"
                ));
                transport.abort(0);
            }
        } else {
            if transport.is_replacement() {
                line_to_stderr(&format!(
                    "rank {rank}: started by rank 0 as a replacement worker rank (MPI_Comm_spawn)"
                ));
            }
            let (stats, progress) = plan.train_worker_rank(&scene, &mut *transport, cfg, &stop)?;
            report(rank, t0.elapsed().as_secs_f64(), &progress, &stats);
        }
        Ok(())
    }

    pub(crate) fn point_mass(a: &PointMassArgs) -> anyhow::Result<()> {
        let cfg = config(a.exchange_every, a.rank_timeout, None)?;
        let mut transport = MpiTransport::init()?;
        let rank = transport.rank();
        let t0 = Instant::now();
        let run = point_mass_config(a.seed, a.workers);
        let result = run_point_mass(&mut transport, cfg, run, a.transitions, a.eval_episodes);
        let (outcome, stats, progress) = match result {
            Ok(r) => r,
            Err(e) => {
                line_to_stderr(&format!("error: rank {rank}: {e}"));
                transport.abort(FAILED);
            }
        };
        report(rank, t0.elapsed().as_secs_f64(), &progress, &stats);
        if let Some(o) = outcome {
            println!(
                "point mass over {} ranks: success {:.2}, best in-training success {:.2}, \
                 return {:.2}, {} transitions, {} updates",
                transport.size(),
                o.success_rate,
                o.best_eval_success,
                o.mean_return,
                o.progress.transitions,
                o.progress.updates
            );
        }
        Ok(())
    }
}
