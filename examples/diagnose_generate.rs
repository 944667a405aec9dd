//! Blind benchmark generator for the mismatch diagnosis (issue 6, section 5).
//!
//! Renders strikes of one mesh with random materials and hides zero, one or two effects of the
//! catalogue in them, at random realistic strengths, with noise. The equations, the parameter
//! ranges and the strength scales are in the module docs of `diffsound::diagnose::inject`;
//! this program adds the FEM side (solves, re-solves, probes) and the files.
//!
//! # Usage
//!
//! ```text
//! mpirun -np 2 target/release/examples/diagnose_generate --out DIR [--cases 10] [--seed 1]
//!        [--mesh examples/bowl/bowl.msh] [--units m] [--mics 4] [--fmax 12000]
//!        [--effects all|NAME,NAME...] [--sample-rate 48000] [--duration 1] [--pre-roll 0.25]
//! ```
//!
//! # A case
//!
//! Drawn from the stream (seed, case index), identically on every rank:
//!
//! * material: ρ = 2700 kg/m³, E ~ U[3e10, 1e11] Pa, ν ~ U[0.15, 0.35]; Rayleigh α ~ U[2, 10]
//!   1/s, β ~ U[1e-8, 5e-8] s;
//! * strike: a unit impulse (1 N·s) at a random surface vertex an object resting on its lowest
//!   side can be hit at (outward normal not more than 60° downwards, above the lowest 5 % of
//!   the height), into the surface along the vertex normal;
//! * microphones (default 4): gains 10^(G/20), G ~ U[−6, 6] dB; positions (always written,
//!   used only by `radiation`) on a sphere of radius R ~ U[0.3, 0.6] m (at least 1.5 times the
//!   bounding box's half-diagonal) about the bounding-box centre, azimuth uniform, elevation
//!   U[0°, 60°] above the horizontal;
//! * noise: white or pink (even odds) at SNR ~ U[50, 70] dB (module docs of `inject`);
//! * the effects of [`inject::schedule_effects`] and their parameters.
//!
//! The P2 modes of the mesh are solved at the case's material (SLEPc, first N modes with N
//! grown until the last lies above `--fmax`; every mode up to `--fmax` is kept): one solve per
//! case. Effects that change K or M (`beating_pair`, `support_contact`, `added_mass`) are all
//! applied to copies of K and M and solved once more. The support's six low modes (body
//! bouncing and rocking on the springs, below half the first free elastic frequency) are not
//! rendered: a body of this size radiates next to nothing at tens of Hz.
//!
//! Each mode becomes a damped sinusoid per microphone (module docs of `inject`). Its drive is
//! |φ_k(x)·n|: the sign of a mode shape is the solver's choice and changes with the number of
//! ranks, so taking the magnitude makes the files the same on any number of ranks (measured:
//! 1 vs 2 ranks agree to float32 rounding). With `radiation` the sign-free product
//! (φ_k(x)·n) × transfer is used instead. The strike starts after `--pre-roll` s of silence,
//! the channels are scaled together so that the loudest peaks at 0.5, reverberated
//! (`reverb`), and noise is added to the whole file.
//!
//! Cost, measured on the bowl (`examples/bowl/bowl.msh`, 53 574 DOF, 1 rank of a shared
//! 2-core machine): about 6 s per SLEPc solve, hence 6–8 s for a case without FEM effects,
//! 12–16 s with them, and 3 s more for the radiation fits (10 cases: 94 s).
//!
//! # Output, in DIR
//!
//! * `case_XXX/mic0.wav` … `micM-1.wav`: 32-bit float, mono, `--sample-rate` Hz,
//!   pre-roll + duration long.
//! * `case_XXX/metadata.toml`: what a user would know: the mesh (path, unit, P2), the density,
//!   the sample rate, the onset time, the strike vertex, position and direction, the
//!   microphone positions and files, the support direction (−z). No labels.
//! * `labels/case_XXX.json` (sealed: never for the tool): the effects with strength and
//!   parameters, E, ν, ρ, α, β, the damping law used, the microphone gains, the noise, and the
//!   rendered modes (undamped and damped frequency, decay, drive, per-microphone amplitude and
//!   phase; `index` counts the modes of the final solve, and an index at or beyond the length
//!   of `base_undamped_hz` is a mode an effect pulled into the band) with the undamped
//!   frequencies before any FEM effect (`base_undamped_hz`; the k-th sorted frequency only
//!   falls with added mass and only rises with springs, so the lists compare index by index).
//!   It parses as `inject::CaseTruth` for [`inject::score`].
//! * `cases.json`: the generator settings and the list of cases (no labels).
//!
//! Progress and per-case timings go to stderr (rank 0).

use diffsound::assembly::{self, Assembled};
use diffsound::audio::excitation::{modal_factor, ContactForce, Response};
use diffsound::audio::radiation::{fit_multipoles, MultipoleSettings, SurfaceQuadrature};
use diffsound::audio::{write_wav, WavFormat};
use diffsound::diagnose::inject::{
    self, Effect, HertzPulse, ModeTrack, NoiseColour, RoomResponse, SplitMix64, ZenerDamping,
};
use diffsound::eigen::{self, EigenConfig, ModeRequest};
use diffsound::fem::Material;
use diffsound::mesh::{self, ReadOptions, TetMesh};
use diffsound::petsc::{Mat, NonzeroPattern, Petsc, PetscInt, Vector};
use mpi::traits::Communicator;
use rustfft::num_complex::Complex64;
use serde_json::json;
use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::time::Instant;

const DENSITY: f64 = 2700.0;
const YOUNGS: (f64, f64) = (3e10, 1e11);
const POISSON: (f64, f64) = (0.15, 0.35);
const ALPHA: (f64, f64) = (2.0, 10.0);
const BETA: (f64, f64) = (1e-8, 5e-8);
const GAIN_DB: f64 = 6.0;
const SNR_DB: (f64, f64) = (50.0, 70.0);
const MIC_RADIUS: (f64, f64) = (0.3, 0.6);
const MIC_ELEVATION_DEG: (f64, f64) = (0.0, 60.0);
/// The support is below the object.
const DOWN: [f64; 3] = [0.0, 0.0, -1.0];
/// Strike vertices lie above this fraction of the height (the support zone is below it).
const STRIKE_CLEARANCE: f64 = 0.05;
/// Support contact: surface vertices within this fraction of the height of the lowest point.
const SUPPORT_BAND: f64 = 0.01;
const SUPPORT_MIN_NODES: usize = 3;
const SUPPORT_DAMPING_RATIO: (f64, f64) = (0.05, 0.3);
const SUPPORT_TANGENTIAL_RATIO: (f64, f64) = (0.1, 0.5);
const ADDED_MASS_NODES: (usize, usize) = (3, 8);
const REVERB_T60_S: (f64, f64) = (0.2, 1.0);
const REVERB_PREDELAY_S: (f64, f64) = (0.001, 0.008);
/// Width of the inhomogeneous sector of `beating_pair` [°].
const SECTOR_WIDTH_DEG: (f64, f64) = (40.0, 80.0);
/// Peak of the loudest channel before reverberation and noise.
const PEAK: f64 = 0.5;
/// The solver never asks for more modes than this.
const MAX_MODES: usize = 800;

struct Args {
    cases: usize,
    seed: u64,
    mesh: PathBuf,
    units: String,
    out: PathBuf,
    mics: usize,
    fmax: f64,
    effects: Vec<Effect>,
    sample_rate: u32,
    duration: f64,
    pre_roll: f64,
}

const USAGE: &str = "usage: diagnose_generate --out DIR [--cases 10] [--seed 1] [--mesh examples/bowl/bowl.msh] [--units m] [--mics 4] [--fmax 12000] [--effects all|NAME,...] [--sample-rate 48000] [--duration 1] [--pre-roll 0.25]";

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        cases: 10,
        seed: 1,
        mesh: PathBuf::from("examples/bowl/bowl.msh"),
        units: "m".into(),
        out: PathBuf::new(),
        mics: 4,
        fmax: 12_000.0,
        effects: Effect::ALL.to_vec(),
        sample_rate: 48_000,
        duration: 1.0,
        pre_roll: 0.25,
    };
    let mut out = None;
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().ok_or(format!("{name} needs a value"));
        fn num<T: std::str::FromStr>(name: &str, v: String) -> Result<T, String> {
            v.parse()
                .map_err(|_| format!("{name}: cannot read {v:?} as a number"))
        }
        match arg.as_str() {
            "--cases" => a.cases = num("--cases", value("--cases")?)?,
            "--seed" => a.seed = num("--seed", value("--seed")?)?,
            "--mesh" => a.mesh = PathBuf::from(value("--mesh")?),
            "--units" => a.units = value("--units")?,
            "--out" => out = Some(PathBuf::from(value("--out")?)),
            "--mics" => a.mics = num("--mics", value("--mics")?)?,
            "--fmax" => a.fmax = num("--fmax", value("--fmax")?)?,
            "--effects" => {
                a.effects =
                    inject::parse_effect_list(&value("--effects")?).map_err(|e| e.to_string())?
            }
            "--sample-rate" => a.sample_rate = num("--sample-rate", value("--sample-rate")?)?,
            "--duration" => a.duration = num("--duration", value("--duration")?)?,
            "--pre-roll" => a.pre_roll = num("--pre-roll", value("--pre-roll")?)?,
            "-h" | "--help" => {
                eprintln!("{USAGE}");
                std::process::exit(0);
            }
            other => return Err(format!("unknown argument {other:?}\n{USAGE}")),
        }
    }
    a.out = out.ok_or(format!("--out DIR is required\n{USAGE}"))?;
    if a.cases == 0 || a.cases > 100_000 {
        return Err(format!("--cases must lie in 1..=100000, got {}", a.cases));
    }
    if a.mics == 0 || a.mics > 64 {
        return Err(format!("--mics must lie in 1..=64, got {}", a.mics));
    }
    if !(8_000..=384_000).contains(&a.sample_rate) {
        return Err(format!(
            "--sample-rate must lie in 8000..=384000 Hz, got {}",
            a.sample_rate
        ));
    }
    if !(a.fmax > 0.0 && a.fmax < 0.5 * a.sample_rate as f64) {
        return Err(format!(
            "--fmax must lie in (0, sample rate / 2), got {}",
            a.fmax
        ));
    }
    if !(a.duration > 0.0 && a.duration <= 60.0 && a.pre_roll >= 0.0 && a.pre_roll <= 60.0) {
        return Err(format!(
            "--duration must lie in (0, 60] s and --pre-roll in [0, 60] s, got {} and {}",
            a.duration, a.pre_roll
        ));
    }
    Ok(a)
}

/// Everything drawn for one case before any solve (identical on every rank).
struct Plan {
    effects: Vec<Effect>,
    strengths: BTreeMap<Effect, f64>,
    material: Material,
    strike_vertex: usize,
    strike_normal: [f64; 3],
    gains_db: Vec<f64>,
    mic_radius: f64,
    mic_positions: Vec<[f64; 3]>,
    noise: NoiseColour,
    snr_db: f64,
    zener_ratio: f64,
    zener_corner_u: f64,
    beating_eps: f64,
    /// q: the sector's Young's modulus is scaled by 1 + qε (its density by 1 + ε).
    beating_stiffness_ratio: f64,
    /// Start and width of the inhomogeneous sector [rad].
    sector: (f64, f64),
    support_bounce_hz: f64,
    support_zeta: f64,
    support_tangential: f64,
    contact: f64,
    room: RoomResponse,
    mass_fraction: f64,
    mass_nodes: Vec<usize>,
    glide: f64,
}

impl Plan {
    fn has(&self, e: Effect) -> bool {
        self.effects.contains(&e)
    }
}

/// Facts about the mesh every case uses.
struct Body {
    mesh: TetMesh,
    mass: f64,
    centroid: [f64; 3],
    centre: [f64; 3],
    diagonal: f64,
    strike_candidates: Vec<(usize, [f64; 3])>,
    support_nodes: Vec<usize>,
}

fn draw_plan(args: &Args, body: &Body, effects: Vec<Effect>, rng: &mut SplitMix64) -> Plan {
    let material = Material {
        youngs_modulus: rng.uniform(YOUNGS.0, YOUNGS.1),
        poisson_ratio: rng.uniform(POISSON.0, POISSON.1),
        density: DENSITY,
        rayleigh_alpha: rng.uniform(ALPHA.0, ALPHA.1),
        rayleigh_beta: rng.uniform(BETA.0, BETA.1),
    };
    let (strike_vertex, normal) = body.strike_candidates[rng.below(body.strike_candidates.len())];
    let gains_db = (0..args.mics)
        .map(|_| rng.uniform(-GAIN_DB, GAIN_DB))
        .collect();
    // Outside the body's bounding sphere with room to spare, whatever its size.
    let mic_radius = rng
        .uniform(MIC_RADIUS.0, MIC_RADIUS.1)
        .max(0.75 * body.diagonal);
    let mic_positions = (0..args.mics)
        .map(|_| {
            let azimuth = rng.uniform(0.0, 2.0 * PI);
            let elevation = rng
                .uniform(MIC_ELEVATION_DEG.0, MIC_ELEVATION_DEG.1)
                .to_radians();
            let c = body.centre;
            [
                c[0] + mic_radius * elevation.cos() * azimuth.cos(),
                c[1] + mic_radius * elevation.cos() * azimuth.sin(),
                c[2] + mic_radius * elevation.sin(),
            ]
        })
        .collect();
    let noise = if rng.unit() < 0.5 {
        NoiseColour::White
    } else {
        NoiseColour::Pink
    };
    let snr_db = rng.uniform(SNR_DB.0, SNR_DB.1);
    // Strengths (radiation's is measured later) and the effects' other parameters; drawn for
    // every case so that the stream does not depend on which effects are present.
    let mut strengths = BTreeMap::new();
    for e in Effect::ALL {
        let u = rng.unit();
        if effects.contains(&e) && !e.strength_scale().measured {
            strengths.insert(e, u);
        }
    }
    let scale = |e: Effect, strengths: &BTreeMap<Effect, f64>| {
        e.strength_scale()
            .value(strengths.get(&e).copied().unwrap_or(0.0))
    };
    let zener_corner_u = rng.unit();
    let sector = (
        rng.uniform(0.0, 2.0 * PI),
        rng.uniform(SECTOR_WIDTH_DEG.0, SECTOR_WIDTH_DEG.1)
            .to_radians(),
    );
    let beating_stiffness_ratio = rng.uniform(-1.0, 1.0);
    let support_zeta = rng.uniform(SUPPORT_DAMPING_RATIO.0, SUPPORT_DAMPING_RATIO.1);
    let support_tangential = rng.uniform(SUPPORT_TANGENTIAL_RATIO.0, SUPPORT_TANGENTIAL_RATIO.1);
    let room = RoomResponse {
        t60_s: rng.log_uniform(REVERB_T60_S.0, REVERB_T60_S.1),
        direct_to_reverberant_db: scale(Effect::Reverb, &strengths),
        predelay_s: rng.uniform(REVERB_PREDELAY_S.0, REVERB_PREDELAY_S.1),
    };
    let mass_centre = body.strike_candidates[rng.below(body.strike_candidates.len())].0;
    let mass_count = ADDED_MASS_NODES.0 + rng.below(ADDED_MASS_NODES.1 - ADDED_MASS_NODES.0 + 1);
    let mass_nodes = inject::nearest_surface_vertices(&body.mesh, mass_centre, mass_count);
    Plan {
        zener_ratio: scale(Effect::NonRayleighDamping, &strengths),
        zener_corner_u,
        beating_eps: scale(Effect::BeatingPair, &strengths),
        sector,
        beating_stiffness_ratio,
        support_bounce_hz: scale(Effect::SupportContact, &strengths),
        support_zeta,
        support_tangential,
        contact: scale(Effect::ContactDuration, &strengths),
        room,
        mass_fraction: scale(Effect::AddedMass, &strengths),
        mass_nodes,
        glide: scale(Effect::PitchGlide, &strengths),
        effects,
        strengths,
        material,
        strike_vertex,
        strike_normal: normal,
        gains_db,
        mic_radius,
        mic_positions,
        noise,
        snr_db,
    }
}

/// Modes kept after a solve: eigenvalues in (λ_min, λ_max] and their vectors.
struct Solved<'p> {
    eigenvalues: Vec<f64>,
    vectors: Vec<Vector<'p>>,
    /// Eigenvalues at or below λ_min that were dropped (the support's modes).
    dropped: Vec<f64>,
    seconds: f64,
    solves: usize,
    warnings: Vec<String>,
}

/// Every mode with λ_min < λ ≤ λ_max: SLEPc's first N modes, N grown until the last one lies
/// above λ_max.
#[allow(clippy::too_many_arguments)]
fn solve_band<'p>(
    petsc: &'p Petsc,
    k: &Mat<'p>,
    m: &Mat<'p>,
    scale: f64,
    lambda_min: f64,
    lambda_max: f64,
    guess: usize,
    expected_rigid: usize,
) -> Result<Solved<'p>, String> {
    let start = Instant::now();
    let mut n = guess.clamp(4, MAX_MODES);
    let mut solves = 0;
    loop {
        let mut cfg = EigenConfig::new(ModeRequest::FirstN(n), scale);
        cfg.expected_rigid = expected_rigid;
        let modes = eigen::solve_modes(petsc, k, m, &cfg).map_err(|e| e.to_string())?;
        solves += 1;
        let top = modes.eigenvalues.last().copied().unwrap_or(0.0);
        if top > lambda_max || n >= MAX_MODES {
            let mut warnings = modes.warnings.clone();
            if top <= lambda_max {
                warnings.push(format!("{MAX_MODES} modes do not reach the frequency limit; the band is cut at {:.0} Hz", eigen::frequency_hz(top)));
            }
            let mut out = Solved {
                eigenvalues: Vec::new(),
                vectors: Vec::new(),
                dropped: Vec::new(),
                seconds: 0.0,
                solves,
                warnings,
            };
            for (lambda, v) in modes.eigenvalues.into_iter().zip(modes.vectors) {
                if lambda <= lambda_min {
                    out.dropped.push(lambda);
                } else if lambda <= lambda_max {
                    out.eigenvalues.push(lambda);
                    out.vectors.push(v);
                }
            }
            out.seconds = start.elapsed().as_secs_f64();
            return Ok(out);
        }
        n = (n + n / 2 + 8).min(MAX_MODES);
    }
}

/// φ_k at the given PETSc dofs, for every mode (collective).
fn probe(vectors: &[Vector<'_>], dofs: &[PetscInt]) -> Result<Vec<Vec<f64>>, String> {
    vectors
        .iter()
        .map(|v| v.gather_indices(dofs).map_err(|e| e.to_string()))
        .collect()
}

fn node_dofs(asm: &Assembled<'_>, nodes: &[usize]) -> Vec<PetscInt> {
    nodes
        .iter()
        .flat_map(|&n| (0..3).map(move |c| asm.layout.global_dof(n, c) as PetscInt))
        .collect()
}

fn frequency(lambda: f64) -> f64 {
    eigen::frequency_hz(lambda)
}

/// The radiation fit of every mode (rank 0).
struct Radiated {
    /// p_k(x_c) [Pa per unit modal amplitude], e^(−iωt) convention, [mode][microphone].
    transfer: Vec<Vec<Complex64>>,
    /// Multipole degree and relative boundary residual of each mode's fit.
    degrees: Vec<usize>,
    residuals: Vec<f64>,
}

/// Per-case wall times [s].
#[derive(Default)]
struct Timing {
    /// SLEPc calls (a solve is repeated with more modes when the band is not yet covered).
    solves: usize,
    base_solve: f64,
    effect_solve: f64,
    radiation: f64,
    render: f64,
    total: f64,
}

fn main() {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(2);
        }
    };
    let universe = match mpi::initialize() {
        Some(u) => u,
        None => {
            eprintln!("error: MPI could not be initialised");
            std::process::exit(1);
        }
    };
    let petsc = match Petsc::initialize(universe, "diagnose_generate", &[]) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    if let Err(e) = run(&petsc, &args) {
        let rank = petsc.rank();
        if rank != 0 {
            std::thread::sleep(std::time::Duration::from_millis(300));
        }
        eprintln!("error (rank {rank}): {e}");
        if petsc.size() > 1 {
            petsc.world().abort(1);
        }
        std::process::exit(1);
    }
}

fn run(petsc: &Petsc, args: &Args) -> Result<(), String> {
    let rank = petsc.rank();
    let say = |msg: String| {
        if rank == 0 {
            eprintln!("{msg}");
        }
    };
    let t_all = Instant::now();
    let unit_scale = mesh::parse_unit(&args.units).map_err(|e| e.to_string())?;
    let read = mesh::read_mesh(
        &args.mesh,
        &ReadOptions {
            unit_scale,
            fix_inverted: false,
        },
    )
    .map_err(|e| e.to_string())?;
    for w in &read.warnings {
        say(format!("warning: {w}"));
    }
    let quadratic = mesh::lift_to_quadratic(&read.mesh);
    drop(read);
    let (lo, hi) = quadratic.bounding_box();
    let diagonal = (0..3).map(|d| (hi[d] - lo[d]).powi(2)).sum::<f64>().sqrt();
    let volume = quadratic.volume();
    let centroid = {
        let mut c = [0.0; 3];
        for e in 0..quadratic.n_tets() {
            let v = quadratic.corner_volume(e);
            for x in quadratic.corner_coords(e) {
                for d in 0..3 {
                    c[d] += 0.25 * v * x[d];
                }
            }
        }
        c.map(|v| v / volume)
    };
    let strike_candidates = inject::strike_candidates(&quadratic, DOWN, STRIKE_CLEARANCE);
    if strike_candidates.is_empty() {
        return Err(format!(
            "{}: no surface vertex to strike",
            args.mesh.display()
        ));
    }
    let support_nodes = inject::support_nodes(&quadratic, DOWN, SUPPORT_BAND, SUPPORT_MIN_NODES);
    let body = Body {
        mass: DENSITY * volume,
        centroid,
        centre: [0, 1, 2].map(|d| 0.5 * (lo[d] + hi[d])),
        diagonal,
        strike_candidates,
        support_nodes,
        mesh: quadratic,
    };
    let asm = assembly::assemble(petsc, &body.mesh).map_err(|e| e.to_string())?;
    say(format!(
        "{}: {} tets, {} P2 nodes ({} DOF) on {} rank(s); mass {:.4} kg at ρ = {DENSITY}, size {:.3} m; {} strike candidates, {} support vertices; assembly {:.2} s",
        args.mesh.display(),
        body.mesh.n_tets(),
        body.mesh.n_nodes(),
        3 * body.mesh.n_nodes(),
        petsc.size(),
        body.mass,
        body.diagonal,
        body.strike_candidates.len(),
        body.support_nodes.len(),
        asm.stats.seconds
    ));
    let schedule = inject::schedule_effects(
        args.cases,
        &args.effects,
        &mut SplitMix64::stream(args.seed, u64::MAX),
    );
    if rank == 0 {
        std::fs::create_dir_all(args.out.join("labels"))
            .map_err(|e| format!("{}: {e}", args.out.display()))?;
    }
    let surface = std::cell::OnceCell::new();
    // (modes below fmax, E) of the last case: the next guess scales the count by E_last/E (the
    // band holds the modes with f ∝ √E below fmax; counts grow like f for shells and plates,
    // faster for solids, and the solve loop corrects any shortfall).
    let mut mode_guess = (20usize, YOUNGS.1);
    let mut listing = Vec::new();
    let mut timings = Vec::new();
    for (index, effects) in schedule.into_iter().enumerate() {
        let name = format!("case_{index:03}");
        let mut rng = SplitMix64::stream(args.seed, index as u64);
        let plan = draw_plan(args, &body, effects, &mut rng);
        let t = generate_case(
            petsc,
            args,
            &body,
            &asm,
            &plan,
            &name,
            index,
            &mut mode_guess,
            &surface,
        )?;
        say(format!(
            "{name}: effects [{}], E {:.3e} ν {:.3}: {} SLEPc solve(s) {:.1} s + {:.1} s, radiation {:.1} s, render {:.1} s, total {:.1} s",
            plan.effects.iter().map(|e| e.name()).collect::<Vec<_>>().join(", "),
            plan.material.youngs_modulus,
            plan.material.poisson_ratio,
            t.solves,
            t.base_solve,
            t.effect_solve,
            t.radiation,
            t.render,
            t.total
        ));
        listing.push(json!({
            "case": name,
            "directory": name,
            "metadata": format!("{name}/metadata.toml"),
            "microphones": (0..args.mics).map(|c| format!("{name}/mic{c}.wav")).collect::<Vec<_>>(),
        }));
        timings.push(t.total);
    }
    if rank == 0 {
        let doc = json!({
            "generator": {
                "program": "examples/diagnose_generate.rs",
                "diffsound_version": env!("CARGO_PKG_VERSION"),
                "seed": args.seed,
                "cases": args.cases,
                "mesh": args.mesh.display().to_string(),
                "units": args.units,
                "microphones": args.mics,
                "max_frequency_hz": args.fmax,
                "sample_rate_hz": args.sample_rate,
                "pre_roll_s": args.pre_roll,
                "duration_s": args.duration,
                "effects_pool": args.effects.iter().map(|e| e.name()).collect::<Vec<_>>(),
                "labels": "labels/case_XXX.json, sealed: for the scorer only",
            },
            "cases": listing,
        });
        write_text(
            &args.out.join("cases.json"),
            &serde_json::to_string_pretty(&doc).map_err(|e| e.to_string())?,
        )?;
        let mean = timings.iter().sum::<f64>() / timings.len() as f64;
        eprintln!(
            "wrote {} cases to {} in {:.1} s ({mean:.1} s per case)",
            args.cases,
            args.out.display(),
            t_all.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

fn write_text(path: &Path, text: &str) -> Result<(), String> {
    diffsound::io::write_atomically(path, |tmp| {
        std::fs::write(tmp, text).map_err(|e| diffsound::io::IoError::Fs {
            path: tmp.to_path_buf(),
            context: "writing".into(),
            source: e,
        })
    })
    .map_err(|e| e.to_string())
}

#[allow(clippy::too_many_arguments)]
fn generate_case<'p>(
    petsc: &'p Petsc,
    args: &Args,
    body: &Body,
    asm: &Assembled<'p>,
    plan: &Plan,
    name: &str,
    index: usize,
    mode_guess: &mut (usize, f64),
    surface: &std::cell::OnceCell<SurfaceQuadrature>,
) -> Result<Timing, String> {
    let t_case = Instant::now();
    let mut timing = Timing::default();
    let rank = petsc.rank();
    let material = &plan.material;
    let scale = eigen::spectrum_scale(material.lame_mu(), DENSITY, body.diagonal);
    let lambda_max = (2.0 * PI * args.fmax).powi(2);
    let (k, m) = asm.operators(material).map_err(|e| e.to_string())?;
    let guess =
        (1.25 * mode_guess.0 as f64 * mode_guess.1 / material.youngs_modulus).ceil() as usize + 4;
    let base = solve_band(petsc, &k, &m, scale, 0.0, lambda_max, guess, 6)?;
    timing.base_solve = base.seconds;
    timing.solves = base.solves;
    if base.eigenvalues.is_empty() {
        return Err(format!("{name}: no elastic mode below {} Hz", args.fmax));
    }
    *mode_guess = (base.eigenvalues.len(), material.youngs_modulus);
    if rank == 0 {
        for w in &base.warnings {
            eprintln!("{name}: warning: {w}");
        }
    }
    let base_eigenvalues = base.eigenvalues.clone();
    let mut beating_label = None;

    // FEM effects: one re-solve with all of them.
    let fem_effects: Vec<Effect> = plan
        .effects
        .iter()
        .copied()
        .filter(|e| e.changes_fem())
        .collect();
    let support = plan.has(Effect::SupportContact);
    let (spring_n, spring_t, dashpot_n, dashpot_t) = {
        let n = body.support_nodes.len() as f64;
        let omega_s = 2.0 * PI * plan.support_bounce_hz;
        let k_n = body.mass * omega_s * omega_s / n;
        let c_n = 2.0 * plan.support_zeta * body.mass * omega_s / n;
        (
            k_n,
            plan.support_tangential * k_n,
            c_n,
            plan.support_tangential * c_n,
        )
    };
    let solved = if fem_effects.is_empty() {
        base
    } else {
        let mut k2 = k.duplicate().map_err(|e| e.to_string())?;
        let mut m2 = m.duplicate().map_err(|e| e.to_string())?;
        if plan.has(Effect::BeatingPair) {
            let sector = inject::sector_mesh(
                &body.mesh,
                body.centroid,
                DOWN,
                plan.sector.0,
                plan.sector.1,
            );
            let sector_volume = sector.volume();
            let part = assembly::assemble(petsc, &sector).map_err(|e| e.to_string())?;
            let (eps, q) = (plan.beating_eps, plan.beating_stiffness_ratio);
            m2.axpy(eps * DENSITY, &part.mass_unit, NonzeroPattern::Subset)
                .map_err(|e| e.to_string())?;
            k2.axpy(
                q * eps * material.lame_lambda(),
                &part.k_lambda,
                NonzeroPattern::Subset,
            )
            .map_err(|e| e.to_string())?;
            k2.axpy(
                q * eps * material.lame_mu(),
                &part.k_mu,
                NonzeroPattern::Subset,
            )
            .map_err(|e| e.to_string())?;
            beating_label = Some(
                json!({"density_increase": eps, "youngs_modulus_increase": q * eps, "sector_axis_point_m": body.centroid, "sector_axis": DOWN,
                "sector_start_rad": plan.sector.0, "sector_width_rad": plan.sector.1, "sector_volume_fraction": sector_volume / body.mesh.volume(),
                "sector": "azimuth psi about the axis, from the projection of +x, counter-clockwise seen from +axis (inject::sector_mesh)"}),
            );
        }
        if support {
            assembly::add_nodal_diagonal(
                petsc,
                &mut k2,
                &asm.layout,
                &body.support_nodes,
                [spring_t, spring_t, spring_n],
            )
            .map_err(|e| e.to_string())?;
        }
        if plan.has(Effect::AddedMass) {
            let per_node = plan.mass_fraction * body.mass / plan.mass_nodes.len() as f64;
            assembly::add_nodal_diagonal(
                petsc,
                &mut m2,
                &asm.layout,
                &plan.mass_nodes,
                [per_node; 3],
            )
            .map_err(|e| e.to_string())?;
        }
        k2.set_symmetric().map_err(|e| e.to_string())?;
        m2.set_symmetric().map_err(|e| e.to_string())?;
        // With springs the six rigid modes become support modes: none is rigid any more, and
        // they are dropped below half the first free elastic mode.
        let (lambda_min, rigid, extra) = if support {
            (0.25 * base.eigenvalues[0], 0, 6)
        } else {
            (0.0, 6, 0)
        };
        let solved = solve_band(
            petsc,
            &k2,
            &m2,
            scale,
            lambda_min,
            lambda_max,
            base.eigenvalues.len() + extra + 4,
            rigid,
        )?;
        timing.effect_solve = solved.seconds;
        timing.solves += solved.solves;
        if rank == 0 {
            for w in &solved.warnings {
                eprintln!("{name}: warning (re-solve): {w}");
            }
            if support && solved.dropped.len() != 6 {
                eprintln!(
                    "{name}: warning: {} support modes below {:.0} Hz, expected 6",
                    solved.dropped.len(),
                    frequency(lambda_min)
                );
            }
        }
        solved
    };

    // Probes (collective): the strike and the support nodes.
    let direction = plan.strike_normal.map(|c| 0.0 - c);
    let strike_values = probe(&solved.vectors, &node_dofs(asm, &[plan.strike_vertex]))?;
    let drive: Vec<f64> = strike_values
        .iter()
        .map(|p| (0..3).map(|c| p[c] * direction[c]).sum())
        .collect();
    let support_extra: Vec<f64> = if support {
        probe(&solved.vectors, &node_dofs(asm, &body.support_nodes))?
            .iter()
            .map(|p| {
                let values: Vec<[f64; 3]> = p.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
                inject::support_damping(&values, dashpot_n, dashpot_t, DOWN)
            })
            .collect()
    } else {
        vec![0.0; solved.eigenvalues.len()]
    };
    // Full shapes on rank 0 for the radiation fit (collective gather).
    let t_rad = Instant::now();
    let mut transfers: Option<Radiated> = None;
    if plan.has(Effect::Radiation) {
        let shapes = asm
            .layout
            .gather_original_order(&solved.vectors)
            .map_err(|e| e.to_string())?;
        if rank == 0 {
            if surface.get().is_none() {
                let q = SurfaceQuadrature::new(&body.mesh).map_err(|e| e.to_string())?;
                let _ = surface.set(q);
            }
            let quadrature = surface.get().expect("set above");
            let settings = MultipoleSettings::default();
            let (mut h, mut degrees, mut residuals) = (Vec::new(), Vec::new(), Vec::new());
            for (shape, &lambda) in shapes.iter().zip(&solved.eigenvalues) {
                let un = quadrature
                    .normal_displacement(shape)
                    .map_err(|e| e.to_string())?;
                let fit = fit_multipoles(quadrature.samples(), &un, lambda.sqrt(), &settings)
                    .map_err(|e| e.to_string())?;
                // The series is reliable only outside the sphere about its centre that holds the
                // surface (module docs of audio::radiation).
                let nearest = plan
                    .mic_positions
                    .iter()
                    .map(|x| {
                        (0..3)
                            .map(|d| (x[d] - fit.centre[d]).powi(2))
                            .sum::<f64>()
                            .sqrt()
                    })
                    .fold(f64::INFINITY, f64::min);
                if nearest <= fit.source_radius {
                    return Err(format!("{name}: a microphone {nearest:.3} m from the radiation fit's centre lies inside its source sphere ({:.3} m)", fit.source_radius));
                }
                h.push(
                    fit.transfer(&plan.mic_positions)
                        .map_err(|e| e.to_string())?,
                );
                degrees.push(fit.degree);
                residuals.push(fit.residual);
            }
            transfers = Some(Radiated {
                transfer: h,
                degrees,
                residuals,
            });
        }
    }
    timing.radiation = t_rad.elapsed().as_secs_f64();
    if rank != 0 {
        timing.total = t_case.elapsed().as_secs_f64();
        return Ok(timing);
    }

    // ---- Rank 0: the sound. ----
    let t_render = Instant::now();
    let fs = args.sample_rate as f64;
    let undamped: Vec<f64> = solved.eigenvalues.iter().map(|&l| frequency(l)).collect();
    let (f_lo, f_hi) = (undamped[0], *undamped.last().expect("at least one mode"));
    let reference_hz = (f_lo * f_hi).sqrt();
    let rayleigh =
        |f: f64| 0.5 * (material.rayleigh_alpha + material.rayleigh_beta * (2.0 * PI * f).powi(2));
    let zener = if plan.has(Effect::NonRayleighDamping) {
        let corner = (f_lo.ln() + plan.zener_corner_u * (f_hi.ln() - f_lo.ln())).exp();
        Some(
            ZenerDamping::matched(
                reference_hz,
                rayleigh(reference_hz),
                plan.zener_ratio,
                corner,
            )
            .map_err(|e| e.to_string())?,
        )
    } else {
        None
    };
    let hertz = if plan.has(Effect::ContactDuration) {
        Some(HertzPulse::new(plan.contact).map_err(|e| e.to_string())?)
    } else {
        None
    };
    let gains: Vec<f64> = plan.gains_db.iter().map(|g| 10f64.powf(g / 20.0)).collect();
    let response = if transfers.is_some() {
        Response::Displacement
    } else {
        Response::Acceleration
    };
    let mut tracks = Vec::new();
    let mut mode_rows = Vec::new();
    let mut contact_db = Vec::new();
    for (kk, &lambda) in solved.eigenvalues.iter().enumerate() {
        let f = undamped[kk];
        let decay = zener.map_or_else(|| rayleigh(f), |z| z.decay(f)) + support_extra[kk];
        if decay * decay >= lambda {
            continue; // overdamped: does not ring
        }
        let omega_d = (lambda - decay * decay).sqrt();
        let s = Complex64::new(-decay, omega_d);
        // A mode's sign is the solver's choice (it changes with the number of ranks). With the
        // radiation transfer the product drive × transfer does not depend on it; without, the
        // drive's magnitude is used, so that the files do not either.
        let c = if transfers.is_some() {
            drive[kk]
        } else {
            drive[kk].abs()
        };
        let mut z = modal_factor(&ContactForce::Impulse, response, decay, omega_d).value * c;
        if let Some(h) = hertz {
            let factor = h.laplace(s);
            contact_db.push(20.0 * factor.norm().log10());
            z *= factor;
        }
        let amplitudes: Vec<Complex64> = match &transfers {
            // e^(−iωt) transfer into the synthesiser's e^(+iωt) convention: the conjugate.
            Some(r) => r.transfer[kk]
                .iter()
                .zip(&gains)
                .map(|(hc, g)| z * hc.conj() * *g)
                .collect(),
            None => gains.iter().map(|g| z * *g).collect(),
        };
        mode_rows.push((kk, f, omega_d / (2.0 * PI), decay));
        tracks.push(ModeTrack {
            frequency_hz: omega_d / (2.0 * PI),
            decay_rate: decay,
            amplitudes,
        });
    }
    let n_pre = (args.pre_roll * fs).round() as usize;
    let n_strike = (args.duration * fs).round() as usize;
    let glide = plan.has(Effect::PitchGlide).then_some(plan.glide);
    let strike = inject::render_tracks(&tracks, args.mics, fs, n_strike, glide)
        .map_err(|e| e.to_string())?;
    let peak = strike.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if peak <= 0.0 || !peak.is_finite() {
        return Err(format!(
            "{name}: the strike is silent (strike vertex {} on a nodal line of every mode?)",
            plan.strike_vertex
        ));
    }
    let out_scale = PEAK / peak;
    let mut channels: Vec<Vec<f64>> = strike
        .into_iter()
        .map(|c| {
            let mut x = vec![0.0; n_pre];
            x.extend(c.iter().map(|v| v * out_scale));
            x
        })
        .collect();
    if plan.has(Effect::Reverb) {
        for (c, ch) in channels.iter_mut().enumerate() {
            let mut room_rng =
                SplitMix64::stream(args.seed ^ 0x0052_4f4f_4d00, (index * 64 + c) as u64);
            let h = plan
                .room
                .impulse_response(fs, ch.len(), &mut room_rng)
                .map_err(|e| e.to_string())?;
            *ch = inject::convolve_truncated(ch, &h);
        }
    }
    let mut noise_rng = SplitMix64::stream(args.seed ^ 0x004e_4f49_5345, index as u64);
    let noise_rms = inject::add_noise(
        &mut channels,
        n_pre..n_pre + n_strike,
        plan.snr_db,
        plan.noise,
        fs,
        &mut noise_rng,
    )
    .map_err(|e| e.to_string())?;

    // ---- Files. ----
    let dir = args.out.join(name);
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for (c, ch) in channels.iter().enumerate() {
        write_wav(
            &dir.join(format!("mic{c}.wav")),
            ch,
            args.sample_rate,
            WavFormat::Float32,
            None,
        )
        .map_err(|e| e.to_string())?;
    }
    write_text(
        &dir.join("metadata.toml"),
        &metadata_toml(args, body, plan, name)?,
    )?;

    // Sealed labels.
    let mut effect_labels = Vec::new();
    for &e in &plan.effects {
        let mut strength = plan.strengths.get(&e).copied().unwrap_or(0.0);
        let parameters = match e {
            Effect::NonRayleighDamping => {
                let z = zener.expect("drawn when present");
                let decays: Vec<f64> = mode_rows.iter().map(|r| r.3).collect();
                let freqs: Vec<f64> = mode_rows.iter().map(|r| r.1).collect();
                let (alpha_fit, beta_fit, misfit) =
                    inject::rayleigh_fit(&freqs, &decays).map_err(|e| e.to_string())?;
                json!({"law": "d(f) = pi f (eta + Delta x/(1+x^2)), x = f/f_c", "loss_factor": z.loss_factor, "relaxation_strength": z.relaxation_strength,
                       "corner_hz": z.corner_hz, "reference_hz": reference_hz, "best_rayleigh_alpha": alpha_fit, "best_rayleigh_beta": beta_fit, "rayleigh_log_misfit": misfit})
            }
            Effect::BeatingPair => {
                let mut p = beating_label.clone().unwrap_or(json!({}));
                let clusters = eigen::find_clusters(&base_eigenvalues, 1e-2);
                let splits: Vec<_> = clusters
                    .iter()
                    .filter(|r| r.end <= solved.eigenvalues.len())
                    .map(|r| {
                        let split = |l: &[f64]| frequency(l[r.end - 1]) - frequency(l[r.start]);
                        json!({"modes": [r.start, r.end - 1], "base_split_hz": split(&base_eigenvalues), "split_hz": split(&solved.eigenvalues)})
                    })
                    .collect();
                p["clusters"] = json!(splits);
                p
            }
            Effect::SupportContact => json!({
                "nodes": body.support_nodes, "bounce_hz": plan.support_bounce_hz, "damping_ratio": plan.support_zeta, "tangential_ratio": plan.support_tangential,
                "normal_stiffness_per_node_n_per_m": spring_n, "tangential_stiffness_per_node_n_per_m": spring_t,
                "normal_dashpot_per_node_n_s_per_m": dashpot_n, "tangential_dashpot_per_node_n_s_per_m": dashpot_t,
                "support_modes_hz": solved.dropped.iter().map(|&l| frequency(l)).collect::<Vec<_>>(),
                "added_decay_per_mode": support_extra,
            }),
            Effect::ContactDuration => {
                json!({"force": "hertz: sin^1.5(pi t/T) on [0, T]", "duration_s": plan.contact, "mode_attenuation_db": contact_db})
            }
            Effect::Reverb => {
                json!({"t60_s": plan.room.t60_s, "direct_to_reverberant_db": plan.room.direct_to_reverberant_db, "predelay_s": plan.room.predelay_s})
            }
            Effect::Radiation => {
                let Radiated {
                    transfer: h,
                    degrees,
                    residuals,
                } = transfers.as_ref().expect("fitted when present");
                let rows: Vec<usize> = mode_rows.iter().map(|r| r.0).collect();
                let levels: Vec<Vec<f64>> = rows
                    .iter()
                    .map(|&kk| h[kk].iter().map(|v| v.norm()).collect())
                    .collect();
                // Weight each mode by its share of the sound (mean |z|² over microphones).
                let weights: Vec<f64> = tracks
                    .iter()
                    .map(|t| t.amplitudes.iter().map(|a| a.norm_sqr()).sum::<f64>())
                    .collect();
                let misfit = inject::rank_one_level_misfit_db(&levels, &weights)
                    .map_err(|e| e.to_string())?;
                strength = e.strength_scale().strength_of(misfit);
                json!({"model": "multipole fit (audio::radiation), default settings", "microphone_radius_m": plan.mic_radius,
                       "rank_one_level_misfit_db": misfit, "multipole_degree_per_mode": degrees, "boundary_residual_per_mode": residuals})
            }
            Effect::AddedMass => {
                json!({"mass_kg": plan.mass_fraction * body.mass, "mass_fraction": plan.mass_fraction, "nodes": plan.mass_nodes,
                "positions_m": plan.mass_nodes.iter().map(|&n| body.mesh.nodes[n]).collect::<Vec<_>>()})
            }
            Effect::PitchGlide => {
                json!({"glide": plan.glide, "law": "f(t) = f0 (1 + g exp(-2 d t))"})
            }
        };
        effect_labels.push(inject::EffectLabel {
            effect: e,
            strength,
            parameters,
        });
    }
    let modes_json: Vec<_> = mode_rows
        .iter()
        .zip(&tracks)
        .map(|(&(kk, f, fd, d), t)| {
            json!({"index": kk, "undamped_hz": f, "frequency_hz": fd, "decay_rate": d, "drive": drive[kk].abs(),
                   "amplitudes": t.amplitudes.iter().map(|a| a.norm() * out_scale).collect::<Vec<_>>(),
                   "phases": t.amplitudes.iter().map(|a| a.arg()).collect::<Vec<_>>()})
        })
        .collect();
    let labels = json!({
        "case": name,
        "effects": effect_labels,
        "youngs_modulus": material.youngs_modulus,
        "poisson_ratio": material.poisson_ratio,
        "density": material.density,
        "rayleigh_alpha": material.rayleigh_alpha,
        "rayleigh_beta": material.rayleigh_beta,
        "damping_law": if zener.is_some() { "zener" } else { "rayleigh" },
        "contact_force": if hertz.is_some() { "hertz" } else { "impulse" },
        "response": if transfers.is_some() { "radiated pressure (displacement x acoustic transfer)" } else { "acceleration" },
        "microphone_gains_db": plan.gains_db,
        "noise": {"colour": plan.noise, "snr_db": plan.snr_db, "rms": noise_rms},
        "output_scale": out_scale,
        "base_undamped_hz": base_eigenvalues.iter().map(|&l| frequency(l)).collect::<Vec<_>>(),
        "modes": modes_json,
    });
    write_text(
        &args.out.join("labels").join(format!("{name}.json")),
        &serde_json::to_string_pretty(&labels).map_err(|e| e.to_string())?,
    )?;
    timing.render = t_render.elapsed().as_secs_f64();
    timing.total = t_case.elapsed().as_secs_f64();
    Ok(timing)
}

/// What a user would know about the recording (module docs): no labels.
fn metadata_toml(args: &Args, body: &Body, plan: &Plan, name: &str) -> Result<String, String> {
    #[derive(serde::Serialize)]
    struct Strike {
        vertex: usize,
        position_m: [f64; 3],
        direction: [f64; 3],
    }
    #[derive(serde::Serialize)]
    struct Meta<'a> {
        case: &'a str,
        mesh: String,
        mesh_unit: &'a str,
        element_order: u32,
        density_kg_m3: f64,
        sample_rate_hz: u32,
        onset_time_s: f64,
        duration_after_onset_s: f64,
        microphone_files: Vec<String>,
        microphone_positions_m: &'a [[f64; 3]],
        support_direction: [f64; 3],
        strike: Strike,
    }
    let meta = Meta {
        case: name,
        mesh: args.mesh.display().to_string(),
        mesh_unit: &args.units,
        element_order: 2,
        density_kg_m3: DENSITY,
        sample_rate_hz: args.sample_rate,
        onset_time_s: (args.pre_roll * args.sample_rate as f64).round() / args.sample_rate as f64,
        duration_after_onset_s: args.duration,
        microphone_files: (0..args.mics).map(|c| format!("mic{c}.wav")).collect(),
        microphone_positions_m: &plan.mic_positions,
        support_direction: DOWN,
        strike: Strike {
            vertex: plan.strike_vertex,
            position_m: body.mesh.nodes[plan.strike_vertex],
            direction: plan.strike_normal.map(|c| 0.0 - c),
        },
    };
    let body_text = toml::to_string(&meta).map_err(|e| e.to_string())?;
    Ok(format!(
        "# diffsound diagnosis benchmark case, written by examples/diagnose_generate.rs.\n\
         # A unit impulse struck the object at strike.vertex (0-based node of the mesh as read),\n\
         # along strike.direction (into the surface), at onset_time_s; the object rests on a\n\
         # support in support_direction. Positions in metres, in the mesh's frame; the mesh path\n\
         # is as given to the generator (relative to its working directory).\n{body_text}"
    ))
}
