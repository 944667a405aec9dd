//! The `diffsound` command line: argument parsing and the MPI/PETSc runtime; each command's flags,
//! their merging with its configuration file and its printing live in a file of its own here, its
//! job in [`crate::workflow`] and its configuration file's format in [`crate::io::config`].
//!
//! Sample runs:
//! ```text
//! mpirun -np 2 diffsound modes --mesh examples/bowl/bowl.msh --material ceramic --modes 20 \
//!        --out out/bowl.h5 --wav out/bowl.wav
//! mpirun -np 2 diffsound modes --config run.toml -- -eps_ncv 80 -st_pc_factor_mat_solver_type mumps
//! ```
//! Everything after `--` goes to PETSc/SLEPc and overrides our defaults.
//!
//! An error that every rank meets together (bad input found in a collective stage, whose
//! results and errors the ranks share) ends the job with its message printed once and exit
//! code 1, PETSc and MPI finalised on every rank. A failure on one rank alone ends the whole
//! MPI job with a message and a non-zero exit (MPI_Abort, after waiting 3 s for the others to
//! fail with it), so a job never hangs waiting for a rank that gave up; a panic does the same
//! at once. A rank that is
//! stopped (SIGSTOP) ends the job after `--rank-timeout` seconds ([`crate::petsc::watchdog`]).

pub mod diagnose;
pub mod fit_geometry;
pub mod fit_material;
pub mod fit_shape;
pub mod impact;
pub mod modes;
pub mod render;
pub mod resolve;
pub mod spectrogram;

use clap::{Parser, Subcommand};
use std::io::IsTerminal;

#[derive(Parser, Debug)]
#[command(
    name = "diffsound",
    version,
    about = "Physics-based modal sound: P2 tet FEM → SLEPc modes → HDF5 and audio"
)]
pub struct Cli {
    /// Print results, warnings and errors only: no progress lines (even with --verbose) and
    /// no notes.
    #[arg(long, short, global = true)]
    pub quiet: bool,
    #[command(subcommand)]
    pub command: Command,
    /// End the MPI job when one of its ranks has been stopped (SIGSTOP) this many seconds, naming
    /// it (default 600, or $DIFFSOUND_RANK_TIMEOUT; 0: never). Watches the ranks on this host.
    #[arg(long, global = true, value_name = "SECS")]
    pub rank_timeout: Option<f64>,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Compute the vibration modes of a free body, write them to HDF5 (+ XDMF) and render a strike.
    Modes(modes::ModesArgs),
    /// Render a strike from a modes HDF5 file to WAV (impact point, direction, force, damping).
    Render(render::RenderArgs),
    /// Spectrogram image of one WAV file or several side by side (e.g. rendered vs recorded).
    Spectrogram(spectrogram::SpectrogramArgs),
    /// Fit damping, Young's modulus and Poisson's ratio to recordings of a strike.
    FitMaterial(fit_material::FitMaterialArgs),
    /// Relative thickness of a hollow body from target eigenvalues (shape from sound).
    FitThickness(fit_shape::FitThicknessArgs),
    /// Geometry from a coarse voxel constraint: an MLP signed distance pre-fitted to voxels and
    /// refined by target eigenvalues.
    FitGeometry(fit_geometry::FitGeometryArgs),
    /// Weight c of a morph c·A + (1 − c)·B of two shapes from target eigenvalues.
    FitMorph(fit_shape::FitMorphArgs),
    /// Where simulation and recording differ, which physics the model left out, and how much
    /// the fit improves with it (report, HDF5, plots).
    Diagnose(diagnose::DiagnoseArgs),
    /// Where was the object struck, and how hard: a likelihood map over its surface from the
    /// mode amplitudes of a recording (HDF5 + XDMF, PNG, JSON).
    LocateImpact(impact::ImpactArgs),
    /// List the material presets with their values.
    Materials,
}

pub use crate::workflow::Progress;
pub use modes::ModesArgs;

/// Rank-0 progress lines on stderr: shown on a terminal (or with --verbose), silent in batch logs
/// and with --quiet. A message longer than [`PROGRESS_WIDTH`] characters is wrapped at spaces,
/// its continuation lines indented under the message, so a log stays readable at 80–160 columns.
pub fn stderr_progress(rank: usize, verbose: bool) -> Progress {
    if rank == 0 && !crate::workflow::quiet() && (verbose || std::io::stderr().is_terminal()) {
        Progress::new(|seconds, msg| {
            let lines = wrap(msg, PROGRESS_WIDTH - PROGRESS_PREFIX);
            let mut text = format!("[{seconds:7.2} s] {}", lines[0]);
            for l in &lines[1..] {
                text.push('\n');
                text.push_str(&" ".repeat(PROGRESS_PREFIX + 2));
                text.push_str(l);
            }
            eprintln!("{text}");
        })
    } else {
        Progress::silent()
    }
}

/// Starts PETSc with `petsc_options` and runs `work` with the rank's progress ([`stderr_progress`]);
/// an error ends the job on every rank ([`fail`], while PETSc is still up).
pub(crate) fn with_petsc<E: ToString>(
    universe: mpi::environment::Universe,
    petsc_options: &[String],
    verbose: bool,
    work: impl FnOnce(&crate::petsc::Petsc, &Progress) -> Result<(), E>,
) -> Result<(), String> {
    let petsc = crate::petsc::Petsc::initialize(universe, "diffsound", petsc_options)
        .map_err(|e| e.to_string())?;
    let (rank, size) = (petsc.rank(), petsc.size());
    // The failure agreement's own communicator: its barrier can only ever meet the other
    // ranks' failure barrier, never a collective of the work (a nonblocking barrier must not
    // meet a blocking one).
    let agreement = {
        use mpi::topology::Communicator;
        petsc.world().duplicate()
    };
    let progress = stderr_progress(rank, verbose);
    match work(&petsc, &progress) {
        Ok(()) => Ok(()),
        Err(e) => {
            let message = e.to_string();
            if failed_together(&agreement, &message) {
                // Every rank is here with its error: PETSc and MPI end together, and the
                // job leaves with exit code 1 and the message alone, without MPI_Abort's
                // screen of complaints.
                drop(progress);
                drop(agreement);
                drop(petsc);
                std::process::exit(1);
            }
            fail(rank, size, &message)
        }
    }
}

/// Seconds a rank that failed waits for the others to fail with it ([`failed_together`]).
/// An input error found inside a collective stage reaches every rank within milliseconds
/// (the stages share their results and errors by broadcast); a rank still working elsewhere
/// only delays the abort by this much.
const AGREEMENT_SECONDS: f64 = 3.0;

/// Whether every rank of `comm` failed (each calls this with its own error `message`): a
/// nonblocking barrier on the agreement communicator, polled for [`AGREEMENT_SECONDS`]. If it
/// completes, rank 0 prints its message once, and each other rank's message that differs from
/// it, and every rank returns true. Otherwise nothing is printed, the barrier is left pending
/// (the caller ends the job with MPI_Abort) and false is returned.
fn failed_together(comm: &mpi::topology::SimpleCommunicator, message: &str) -> bool {
    use mpi::collective::CommunicatorCollectives;
    use mpi::point_to_point::{Destination, Source};
    use mpi::topology::Communicator;
    let mut pending = comm.immediate_barrier();
    let started = std::time::Instant::now();
    loop {
        match pending.test() {
            Ok(_) => break,
            Err(still) => pending = still,
        }
        if started.elapsed().as_secs_f64() > AGREEMENT_SECONDS {
            // The request stays pending: MPI_Abort follows, and a dropped pending request
            // would panic first.
            std::mem::forget(pending);
            return false;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    let (rank, size) = (comm.rank(), comm.size());
    if rank == 0 {
        eprintln!("error: {message}");
        for r in 1..size {
            let (theirs, _) = comm.process_at_rank(r).receive_vec::<u8>();
            let theirs = String::from_utf8_lossy(&theirs);
            if theirs != message {
                eprintln!("error (rank {r}): {theirs}");
            }
        }
    } else {
        comm.process_at_rank(0).send(message.as_bytes());
    }
    true
}

/// Width (characters) progress lines are wrapped at, the `[   1.23 s] ` prefix included.
pub const PROGRESS_WIDTH: usize = 160;
const PROGRESS_PREFIX: usize = 12;

/// `text` cut into lines of at most `width` characters at spaces (a word longer than `width`
/// stays whole on its own line); continuation lines are 2 characters narrower, for the indent
/// they get. Existing line breaks are kept.
pub fn wrap(text: &str, width: usize) -> Vec<String> {
    let width = width.max(20);
    let mut lines = Vec::new();
    for para in text.split('\n') {
        // Leading spaces indent the message (nested progress lines): keep them.
        let body = para.trim_start_matches(' ');
        let mut line = " ".repeat(para.len() - body.len());
        let mut len = line.len();
        for word in body.split(' ') {
            let wl = word.chars().count();
            let limit = if lines.is_empty() { width } else { width - 2 };
            if len > 0 && !line.trim().is_empty() && len + 1 + wl > limit {
                lines.push(std::mem::take(&mut line));
                len = 0;
            }
            if !line.trim().is_empty() {
                line.push(' ');
                len += 1;
            }
            line.push_str(word);
            len += wl;
        }
        lines.push(line);
    }
    lines
}

/// Ends the whole MPI job: the one way out after an error or panic on any rank.
fn abort_job(code: i32) -> ! {
    // SAFETY: MPI is initialised whenever this is reachable from `main` after `initialize`.
    unsafe {
        mpi::ffi::MPI_Abort(mpi::ffi::RSMPI_COMM_WORLD, code);
    }
    std::process::exit(code)
}

/// Entry point of the binary.
pub fn main() {
    crate::petsc::pin_blas_threads();
    ignore_file_size_signal();
    let cli = Cli::parse();
    let limit = match crate::petsc::watchdog::limit(cli.rank_timeout) {
        Ok(l) => l,
        Err(message) => {
            eprintln!("error: {message}");
            std::process::exit(1);
        }
    };
    crate::workflow::set_quiet(cli.quiet);
    match cli.command {
        Command::Materials => print_materials(),
        Command::Modes(args) => run_under_mpi(limit, |universe| modes::run(universe, args)),
        Command::FitMaterial(args) => {
            run_under_mpi(limit, |universe| fit_material::run(universe, args))
        }
        Command::Diagnose(args) => run_under_mpi(limit, |universe| diagnose::run(universe, args)),
        Command::LocateImpact(args) => run_under_mpi(limit, |universe| impact::run(universe, args)),
        Command::FitThickness(args) => {
            run_under_mpi(limit, |universe| fit_shape::run_thickness(universe, args))
        }
        Command::FitMorph(args) => {
            run_under_mpi(limit, |universe| fit_shape::run_morph(universe, args))
        }
        Command::FitGeometry(args) => {
            run_under_mpi(limit, |universe| fit_geometry::run(universe, args))
        }
        Command::Render(args) => run_serial(render::run(args)),
        Command::Spectrogram(args) => run_serial(spectrogram::run(args)),
    }
}

/// Jobs that need neither MPI nor PETSc: an error is printed once and the exit code is 1.
fn run_serial(result: Result<(), String>) {
    if let Err(message) = result {
        eprintln!("error: {message}");
        std::process::exit(1);
    }
}

/// A write past the file size limit (`ulimit -f`) kills the process with SIGXFSZ by default,
/// after the work and with no word on what happened. Ignored, the write fails with EFBIG
/// instead, which the writers report on the output's path ([`crate::io::atomic`]).
fn ignore_file_size_signal() {
    // SAFETY: setting a signal's disposition to "ignore" before any other thread starts.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

fn print_materials() {
    println!(
        "{:<11} {:>12} {:>6} {:>9} {:>8} {:>9}",
        "preset", "E [Pa]", "ν", "ρ", "α", "β"
    );
    for name in crate::fem::Material::preset_names() {
        let m = crate::fem::Material::preset(name).expect("listed preset exists");
        println!(
            "{:<11} {:>12.3e} {:>6.3} {:>9.1} {:>8.3} {:>9.2e}",
            name, m.youngs_modulus, m.poisson_ratio, m.density, m.rayleigh_alpha, m.rayleigh_beta
        );
    }
}

fn run_under_mpi(
    rank_timeout: Option<std::time::Duration>,
    job: impl FnOnce(mpi::environment::Universe) -> Result<(), String>,
) {
    let Some(universe) = mpi::initialize() else {
        eprintln!("error: MPI could not be initialised");
        std::process::exit(2);
    };
    let rank = {
        use mpi::topology::Communicator;
        universe.world().rank()
    };
    let size = {
        use mpi::topology::Communicator;
        universe.world().size()
    };
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        eprintln!("diffsound: rank {rank} of {size} panicked; aborting the MPI job");
        default_hook(info);
        abort_job(101);
    }));
    crate::petsc::watchdog::start(&universe.world(), rank_timeout);

    if let Err(message) = job(universe) {
        fail(rank as usize, size as usize, &message);
    }
}

/// Reports an error and ends the job on every rank. Called before the PETSc runtime is dropped,
/// because finalising is collective and the other ranks may be waiting elsewhere.
pub(crate) fn fail(rank: usize, size: usize, message: &str) -> ! {
    // Every rank usually meets the same input error; let rank 0 speak first so the message is
    // printed once, then whoever is left aborts the job.
    if rank != 0 {
        std::thread::sleep(std::time::Duration::from_millis(500));
        eprintln!("error (rank {rank}): {message}");
    } else {
        eprintln!("error: {message}");
    }
    // An input error found before PETSc starts returns through the job and drops the MPI
    // universe: every rank has then met the same error and finalised, and MPI_Abort after
    // MPI_Finalize would only add a screen of MPI complaints.
    if size > 1 && !mpi::environment::is_finalized() {
        abort_job(1);
    }
    std::process::exit(1);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_progress_lines_wrap_at_spaces() {
        let msg = (0..60)
            .map(|k| format!("{k}.5"))
            .collect::<Vec<_>>()
            .join(", ");
        let lines = wrap(&msg, 60);
        assert!(lines.len() > 3, "{lines:?}");
        assert_eq!(lines.join(" "), msg);
        assert!(lines[0].chars().count() <= 60);
        assert!(
            lines[1..].iter().all(|l| l.chars().count() <= 58),
            "{lines:?}"
        );
        // A short line is left alone; a word longer than the width stays whole.
        assert_eq!(wrap("basis: 4 solves", 60), vec!["basis: 4 solves"]);
        assert_eq!(wrap("    glide: a b", 60), vec!["    glide: a b"]);
        let long = "x".repeat(80);
        assert_eq!(
            wrap(&format!("a {long} b"), 40),
            vec!["a", long.as_str(), "b"]
        );
    }

    #[test]
    fn quiet_is_a_global_flag() {
        let cli = Cli::try_parse_from(["diffsound", "materials", "--quiet"]).unwrap();
        assert!(cli.quiet);
        let cli = Cli::try_parse_from(["diffsound", "-q", "materials"]).unwrap();
        assert!(cli.quiet);
        let cli = Cli::try_parse_from(["diffsound", "materials"]).unwrap();
        assert!(!cli.quiet);
    }

    #[test]
    fn help_has_no_tracker_words() {
        use clap::CommandFactory;
        let mut cmd = Cli::command();
        let mut texts = vec![cmd.render_long_help().to_string()];
        for sub in cmd.get_subcommands_mut() {
            texts.push(sub.render_long_help().to_string());
        }
        for t in &texts {
            assert!(!t.to_lowercase().contains("issue"), "{t}");
        }
    }
}
