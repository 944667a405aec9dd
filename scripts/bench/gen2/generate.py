#!/usr/bin/python3
"""Generator 2 for the mismatch diagnosis: recordings made independently of diffsound's own
generator (examples/diagnose_generate.rs and diffsound::diagnose::inject share no code or
convention with this file).

Only the modal solve is diffsound's (`diffsound modes`, the forward engine that is tested
against analytic solutions); everything after it -- the objects, the strike, the response
quantity, the microphones, the radiation, the damping law, the effects and the noise -- is
written here afresh in NumPy, with conventions chosen to differ from the first generator:

* objects: a thin plate, a tube, a small bowl and a steel bar (``*.geo`` beside this file),
  not the ceramic bowl of ``../shared``; 2 to 8 microphones;
* response: displacement, velocity, acceleration or pressure-like (velocity times a radiation
  efficiency rising as f^1.5 below coincidence) -- drawn per case, never told to the tool;
* microphones: gain +-8 dB and a frequency tilt (f/1 kHz)^s with s ~ U[-0.6, 0.6] each;
* radiation: a log-normal level per mode and microphone (sigma 0.4 in ln, i.e. about
  +-50 %), and a random phase per mode and microphone;
* baseline damping: a Rayleigh law given by decay rates at 1 kHz and 8 kHz;
* noise: white or brown (integrated white) at 40-60 dB SNR below the loudest channel's peak.

Effects (each case has zero or one; names as the tool reports them):

* non_rayleigh_damping -- a power law d = d1 (f / 1 kHz)^p, p ~ U[0.3, 1.0];
* beating_pair -- the near-degenerate pairs of the tube and the bowl split by 0.3-1.2 %
  (each pair by its own random fraction of that);
* support_contact -- springs and dashpots on a strip of the lowest surface (a plate or a bar
  on a rubber strip across it, a tube on a rail, a bowl on its foot ring), Ritz in the free
  modes;
* contact_duration -- a half-sine force of duration tau, first spectral null at 0.45-0.85 of
  the band's top;
* reverb_noise -- each channel convolved with its own room: a direct path plus exponentially
  decaying Gaussian noise (RT60 0.25-1.0 s, direct-to-reverberant ratio -2-6 dB);
* pitch_glide -- f(t) = f_k (1 + g_k e^(-2 d_k t)), g_k = g (a_k / max a)^2, g ~ U[0.4, 1.2] %;
* added_mass -- 1.5-6 % of the body's mass lumped on the 3-6 surface vertices nearest a
  random surface vertex, solved in full (``examples/mass_probe.rs``: the same P2 model with the
  point masses on its mass matrix). Ritz in the free modes, as the support is made, cannot give
  a mass on a few vertices the local deformation it causes: against a full solve that put a
  cup's mass-loaded local mode at 8646 Hz instead of 7357 Hz and moved a tube's modes by up to
  2.5 % (docs/diagnose_benchmarks.md, "twenty-second"); the strip of soft springs agrees with a
  full solve within 0.002 %.

A support or an added mass must be observable: it must move some in-band mode's frequency by
0.1 % or add 1 1/s to its decay rate, or the object and the effect are drawn again (the label
records the draws, the largest relative shift and the largest added decay rate). A support on
the cup's foot ring rarely is (its wine-glass modes hardly move the foot).

Controls: clean cases, and "uniform shift" cases where the tool is told E 4-8 % off.

Writes DIR/case_XXX/{mic*.wav, run.sh} (run.sh: the diagnose command a user would type) and
DIR/labels/case_XXX.json (sealed). Usage:

    python3 scripts/bench/gen2/generate.py --out out/gen2 --cases 24 --seed 7 [--np 2]
"""
import argparse
import json
import os
import subprocess
import sys
import wave

import h5py
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
BIN = os.path.join(ROOT, "target/release/diffsound")  # set by --bin
PROBE = os.path.join(ROOT, "target/release/examples/mass_probe")  # set by --probe
ONLY_OBJECT = None  # set by --object (focused calibration sets only)
SR = 44100
FMAX = 9000.0
DURATION = 1.5
PRE = 0.2

OBJECTS = {
    # name: (geo, density, E range, nu choices, support axis (lowest along -z), effects allowed)
    "plate": ("plate.geo", 2700.0, (6.5e10, 7.5e10), (0.31, 0.34), False),
    "tube": ("tube.geo", 2230.0, (5.8e10, 6.8e10), (0.20, 0.23), True),
    "cup": ("cup.geo", 2400.0, (6.0e10, 9.0e10), (0.18, 0.22), True),
    # Added 2026-12-06 (after seed 211), an object no rule was shaped on.
    "bar": ("bar.geo", 7850.0, (1.9e11, 2.1e11), (0.28, 0.30), False),
}
EFFECTS = ["non_rayleigh_damping", "beating_pair", "support_contact", "contact_duration",
           "reverb_noise", "pitch_glide", "added_mass"]


def run(cmd, log):
    with open(log, "w") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        sys.exit(f"failed: {' '.join(cmd)} (see {log})")


def mesh_object(name, work):
    geo = os.path.join(HERE, OBJECTS[name][0])
    msh = os.path.join(work, f"{name}.msh")
    if not os.path.exists(msh):
        run(["gmsh", geo, "-3", "-format", "msh22", "-o", msh], msh + ".log")
    return msh


def fmax_at_reference(name):
    """The highest frequency solved at E = 1e11 [Hz]: 1.7 FMAX at the softest E of the
    object's range, so the Ritz bases of the FEM effects reach past the band."""
    return 1.7 * FMAX * np.sqrt(1e11 / OBJECTS[name][2][0])


def solve_modes(name, msh, nu, rho, np_ranks, work):
    """Free modes at E = 1e11 (scaled per case: lambda ~ E at fixed nu), up to
    fmax_at_reference."""
    out = os.path.join(work, f"{name}_nu{nu:.3f}.h5")
    if not os.path.exists(out):
        cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(np_ranks),
               BIN, "modes", "--mesh", msh,
               "--youngs", "1e11", "--poisson", str(nu), "--density", str(rho),
               "--fmax", f"{fmax_at_reference(name):.1f}", "--out", out]
        run(cmd, out + ".log")
    with h5py.File(out, "r") as f:
        lam = f["/modes/eigenvalues"][:]
        shapes = f["/modes/shapes"][:]
        nodes = f["/mesh/nodes"][:]
        tets = f["/mesh/tets"][:].astype(np.int64)
    return lam, shapes, nodes, tets


def surface(nodes, tets):
    """Boundary corner vertices, their outward unit normals (area weighted), and the volume."""
    corners = tets[:, :4]
    faces = {}
    vol = 0.0
    for t in corners:
        p = nodes[t]
        v6 = np.dot(np.cross(p[1] - p[0], p[2] - p[0]), p[3] - p[0])
        vol += abs(v6) / 6.0
        for opp in range(4):
            f = tuple(sorted(int(x) for i, x in enumerate(t) if i != opp))
            if f in faces:
                faces[f] = None
            else:
                faces[f] = int(t[opp])
    normals = np.zeros_like(nodes)
    for f, opp in faces.items():
        if opp is None:
            continue
        a, b, c = (nodes[i] for i in f)
        n = 0.5 * np.cross(b - a, c - a)
        if np.dot(n, nodes[opp] - a) > 0:
            n = -n
        for i in f:
            normals[i] += n
    verts = np.array(sorted({i for f, o in faces.items() if o is not None for i in f}))
    nn = normals[verts]
    nn /= np.linalg.norm(nn, axis=1)[:, None]
    return verts, nn, vol


def loaded_modes(name, msh, nu, rho, mass_kg, region, np_ranks, work):
    """Free modes of the body with mass_kg lumped evenly on the vertices of region (three
    components each), at E = 1e11 like solve_modes and up to the same frequency (lambda ~ E at
    fixed nu and fixed added mass: the point masses are on M, which E does not touch)."""
    out = os.path.join(work, "added_mass.h5")
    cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(np_ranks), PROBE, msh,
           "1e11", str(nu), str(rho), f"{fmax_at_reference(name):.1f}", "mass",
           repr(float(mass_kg))]
    cmd += [str(int(v)) for v in region] + ["out", out]
    run(cmd, out + ".log")
    with h5py.File(out, "r") as f:
        return f["/modes/eigenvalues"][:], f["/modes/shapes"][:]


def ritz(lam, shapes, stiff_nodes, k_diag, mass_nodes, m_node):
    """Modes of K + sum k_v D, M + sum m_v I in the basis of the free modes (mass-normalised):
    K_r = diag(lam) + sum_v Phi_v^T D_v Phi_v, M_r = I + m sum_v Phi_v^T Phi_v."""
    n = len(lam)
    kr = np.diag(lam.astype(float))
    mr = np.eye(n)
    for v in stiff_nodes:
        p = shapes[:, v, :]  # [n, 3]
        kr += p @ np.diag(k_diag) @ p.T
    for v in mass_nodes:
        p = shapes[:, v, :]
        mr += m_node * (p @ p.T)
    # Symmetric-definite generalised problem via Cholesky of M_r.
    lc = np.linalg.cholesky(mr)
    li = np.linalg.inv(lc)
    w, q = np.linalg.eigh(li @ kr @ li.T)
    coef = li.T @ q  # modal coordinates of the new mass-normalised shapes
    new_shapes = np.einsum("kj,knd->jnd", coef, shapes)
    return w, new_shapes


def half_sine_spectrum(f, tau):
    """|F(f)| / |F(0)| of a half-sine pulse of duration tau."""
    x = 2.0 * f * tau  # = omega tau / pi
    out = np.empty_like(f)
    near = np.abs(x - 1.0) < 1e-6
    out[~near] = np.abs(np.cos(np.pi * x[~near] / 2.0) / (1.0 - x[~near] ** 2))
    out[near] = np.pi / 4.0
    return out


def write_wav(path, x):
    pcm = np.clip(np.round(x * 32767.0), -32768, 32767).astype("<i2")
    with wave.open(path, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(SR)
        w.writeframes(pcm.tobytes())


def make_case(idx, rng, effect, control, work, out, np_ranks):
    for attempt in range(1, MAX_DRAWS + 1):
        drawn = draw_object(rng, effect, control, np_ranks, work)
        (name, msh, rho, nu, youngs, lam, shapes, nodes, verts, normals, truth, support_decay,
         shift, in_band) = drawn
        if effect not in ("support_contact", "added_mass") or observable(shift, support_decay, in_band):
            break
    else:
        sys.exit(f"case {idx}: no observable {effect} in {MAX_DRAWS} draws")
    truth["params"].update(draws=attempt, largest_shift=float(np.abs(shift[in_band]).max(initial=0.0)),
                           largest_added_decay=float(support_decay[in_band].max(initial=0.0)))
    return finish_case(idx, rng, effect, control, out, name, msh, rho, nu, youngs, lam, shapes,
                       nodes, verts, normals, truth, support_decay)


# A concealed FEM effect must have a consequence in the recording: it must move some in-band
# mode's frequency by at least MIN_SHIFT (relative) or add at least MIN_ADDED_DECAY [1/s] to its
# decay rate (the baseline rates are 2-90 1/s); otherwise the object and the effect are drawn
# again. Without the floor, a support on the cup's foot ring (whose wine-glass modes barely move
# the foot) added at most 0.003 1/s and shifted no frequency by 1e-4: a label with nothing to find.
MIN_SHIFT = 1e-3
MIN_ADDED_DECAY = 1.0
MAX_DRAWS = 50


def observable(shift, added, in_band):
    return bool(np.any(in_band & ((np.abs(shift) >= MIN_SHIFT) | (added >= MIN_ADDED_DECAY))))


def draw_object(rng, effect, control, np_ranks, work):
    name = str(rng.choice(list(OBJECTS)))
    if effect == "beating_pair":
        name = str(rng.choice(["tube", "cup"]))
    if ONLY_OBJECT is not None:
        name = ONLY_OBJECT
    geo, rho, (e_lo, e_hi), nus, _ = OBJECTS[name]
    nu = float(rng.choice(nus))
    youngs = float(rng.uniform(e_lo, e_hi))
    msh = mesh_object(name, work)
    lam, shapes, nodes, tets = solve_modes(name, msh, nu, rho, np_ranks, work)
    lam = lam * youngs / 1e11
    verts, normals, vol = surface(nodes, tets)
    mass = rho * vol
    truth = {"object": name, "youngs": youngs, "poisson": nu, "density": rho, "effects": [],
             "control": control, "params": {}}

    # FEM effects, Ritz in the free modes.
    lam_free = lam.copy()
    z = nodes[:, 2]
    height = z.max() - z.min()
    if effect == "support_contact":
        low = verts[z[verts] < z.min() + 0.03 * height]
        if name in ("plate", "bar"):  # a rubber strip across the underside
            x = nodes[low, 0]
            x0 = rng.uniform(x.min() + 0.2 * np.ptp(x), x.max() - 0.2 * np.ptp(x))
            low = low[np.abs(x - x0) < 0.012]
        kz = float(rng.uniform(0.02, 0.08) * lam[0] * mass / max(len(low), 1))
        lam, shapes = ritz(lam, shapes, low, np.array([0.3 * kz, 0.3 * kz, kz]), [], 0.0)
        # Dashpots at the same nodes: extra decay 0.5 c sum |phi_z|^2 per mode.
        c = float(rng.uniform(3.0, 12.0) * mass / max(len(low), 1))
        support_decay = 0.5 * c * np.sum(shapes[:, low, 2] ** 2, axis=1)
        truth["params"].update(support_vertices=int(len(low)), spring_n_per_m=kz, dashpot=c)
    else:
        support_decay = np.zeros(len(lam))
    if effect == "added_mass":
        centre = int(rng.choice(verts))
        d = np.linalg.norm(nodes[verts] - nodes[centre], axis=1)
        k = int(rng.integers(3, 7))
        region = verts[np.argsort(d)[:k]]
        frac = float(rng.uniform(0.015, 0.06))
        lam, shapes = loaded_modes(name, msh, nu, rho, frac * mass, region, np_ranks, work)
        lam = lam * youngs / 1e11
        truth["params"].update(mass_fraction=frac, region=[int(v) for v in region],
                               mass_model="full solve")
    # Mode k of the perturbed set is compared with free mode k: the support (Ritz in the free
    # modes) keeps their number; a full solve of a mass may add a local mode, which then shows as
    # a large shift (observable either way).
    n = min(len(lam), len(lam_free))
    lam, shapes, support_decay = lam[:n], shapes[:n], support_decay[:n]
    f_now = np.sqrt(np.maximum(lam, 0.0)) / (2 * np.pi)
    in_band = (f_now > 60.0) & (f_now < FMAX)
    shift = np.sqrt(np.maximum(lam, 0.0) / np.maximum(lam_free[:n], 1e-300)) - 1.0
    return (name, msh, rho, nu, youngs, lam, shapes, nodes, verts, normals, truth, support_decay,
            shift, in_band)


def finish_case(idx, rng, effect, control, out, name, msh, rho, nu, youngs, lam, shapes, nodes,
                verts, normals, truth, support_decay):
    z = nodes[:, 2]
    height = z.max() - z.min()
    freqs = np.sqrt(np.maximum(lam, 0.0)) / (2 * np.pi)
    if effect == "beating_pair":
        split = float(rng.uniform(0.003, 0.012))
        n_pairs = 0
        k = 0
        while k < len(freqs) - 1:
            if freqs[k + 1] / freqs[k] - 1.0 < 0.002 and freqs[k] < FMAX:
                mean = 0.5 * (freqs[k] + freqs[k + 1])
                s = split * rng.uniform(0.5, 1.0)
                freqs[k], freqs[k + 1] = mean * (1 - s / 2), mean * (1 + s / 2)
                n_pairs += 1
                k += 2
            else:
                k += 1
        truth["params"].update(split=split, pairs=n_pairs)

    # The strike: a random surface vertex, into the surface, not on the lowest 5 %.
    cand = verts[z[verts] > z.min() + 0.05 * height]
    pick = int(rng.integers(len(cand)))
    strike = int(cand[pick])
    normal = normals[np.searchsorted(verts, strike)]
    drive = shapes[:, strike, :] @ (-normal)

    band = (freqs > 60.0) & (freqs < FMAX)
    freqs, drive, support_decay = freqs[band], drive[band], support_decay[band]
    w = 2 * np.pi * freqs

    # Damping.
    d1k = float(rng.uniform(2.0, 8.0))
    if effect == "non_rayleigh_damping":
        p = float(rng.uniform(0.3, 1.0))
        decay = d1k * (freqs / 1000.0) ** p
        truth["params"].update(damping_power=p, decay_at_1khz=d1k)
    else:
        d8k = float(rng.uniform(25.0, 90.0))
        w1, w8 = 2 * np.pi * 1000.0, 2 * np.pi * 8000.0
        beta2 = (d8k - d1k) / (w8 ** 2 - w1 ** 2)
        alpha2 = max(d1k - beta2 * w1 ** 2, 0.2)
        decay = alpha2 + beta2 * w ** 2
        truth["params"].update(rayleigh_alpha=2 * alpha2, rayleigh_beta=2 * beta2)
    decay = decay + support_decay

    # Force spectrum (an impulse unless a contact duration is concealed).
    force = np.ones_like(freqs)
    if effect == "contact_duration":
        tau = 1.5 / (rng.uniform(0.45, 0.85) * FMAX)
        force = half_sine_spectrum(freqs, tau)
        truth["params"].update(contact_s=tau)

    # Response quantity, microphones, radiation.
    response = str(rng.choice(["displacement", "velocity", "acceleration", "pressure"]))
    power = {"displacement": 0.0, "velocity": 1.0, "acceleration": 2.0, "pressure": 2.5}[response]
    # Two microphones in half the cases (one is held out: the least a user can give).
    n_mics = 2 if rng.uniform() < 0.5 else int(rng.integers(3, 9))
    mic_gain = 10 ** (rng.uniform(-8, 8, n_mics) / 20)
    mic_tilt = rng.uniform(-0.6, 0.6, n_mics)
    radiation = np.exp(rng.normal(0.0, 0.4, (len(freqs), n_mics)))
    phase = rng.uniform(0, 2 * np.pi, (len(freqs), n_mics))
    # Displacement of a unit impulse: (phi . n) phi / omega; the response quantity multiplies by
    # omega^power.
    base = force * drive * w ** (power - 1.0)
    amp = base[:, None] * radiation * mic_gain[None, :] * (freqs[:, None] / 1000.0) ** mic_tilt[None, :]
    truth.update(response=response, microphones=n_mics, mic_tilt=mic_tilt.tolist())

    glide = np.zeros(len(freqs))
    if effect == "pitch_glide":
        g = float(rng.uniform(0.004, 0.012))
        a = np.abs(drive) * w ** (power - 1.0)
        glide = g * (a / a.max()) ** 2
        truth["params"].update(glide=g)

    n = int(round((PRE + DURATION) * SR))
    t = np.arange(n) / SR - PRE
    live = t >= 0
    tt = t[live]
    sig = np.zeros((n_mics, n))
    for k in range(len(freqs)):
        env = np.exp(-decay[k] * tt)
        if glide[k] > 0:
            # phase = 2 pi f_k (t + g (1 - e^{-2 d t}) / (2 d))
            ph = 2 * np.pi * freqs[k] * (tt + glide[k] * (1 - np.exp(-2 * decay[k] * tt)) / (2 * decay[k]))
        else:
            ph = 2 * np.pi * freqs[k] * tt
        for c in range(n_mics):
            sig[c, live] += amp[k, c] * env * np.sin(ph + phase[k, c])
    if effect == "reverb_noise":
        rt60 = float(rng.uniform(0.25, 1.0))
        drr_db = float(rng.uniform(-2.0, 6.0))
        m = int(rt60 * SR)
        th = np.arange(m) / SR
        for c in range(n_mics):
            tail = rng.normal(0, 1, m) * np.exp(-6.91 * th / rt60)
            tail[: int(0.002 * SR)] = 0.0
            tail *= np.sqrt(10 ** (-drr_db / 10) / np.sum(tail ** 2))
            ir = np.concatenate([[1.0], tail[1:]])
            sig[c] = np.convolve(sig[c], ir)[:n]
        truth["params"].update(rt60=rt60, drr_db=drr_db)
    peak = np.abs(sig).max()
    sig *= 0.5 / peak
    snr = float(rng.uniform(40, 60))
    colour = str(rng.choice(["white", "brown"]))
    for c in range(n_mics):
        noise = rng.normal(0, 1, n)
        if colour == "brown":
            noise = np.cumsum(noise)
            noise -= np.convolve(noise, np.ones(501) / 501, mode="same")
        noise *= 0.5 * 10 ** (-snr / 20) / np.sqrt(np.mean(noise ** 2))
        sig[c] += noise
    truth.update(snr_db=snr, noise=colour, strike_vertex=strike, n_modes_in_band=int(len(freqs)))

    case = os.path.join(out, f"case_{idx:03d}")
    os.makedirs(case, exist_ok=True)
    args = ["--mesh", os.path.abspath(msh), "--density", str(rho), "--strike-vertex", str(strike)]
    for c in range(n_mics):
        wav = os.path.join(case, f"mic{c}.wav")
        write_wav(wav, sig[c])
        args += ["--recording", wav]
    if control == "uniform_shift":
        off = float(rng.choice([-1, 1]) * rng.uniform(0.04, 0.08))
        args += ["--youngs", f"{youngs * (1 + off):.6e}", "--poisson", str(nu)]
        truth["params"].update(youngs_told=youngs * (1 + off))
    with open(os.path.join(case, "args.json"), "w") as f:
        json.dump(args, f)
    if effect:
        truth["effects"] = [effect]
    with open(os.path.join(out, "labels", f"case_{idx:03d}.json"), "w") as f:
        json.dump(truth, f, indent=1)
    return name, effect, control, n_mics, response


def main():
    global BIN, ONLY_OBJECT, PROBE
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--cases", type=int, default=24)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--np", type=int, default=2)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target/release/diffsound"),
                    help="the diffsound binary (a frozen build for a blind run)")
    ap.add_argument("--probe", default=PROBE,
                    help="examples/mass_probe, which solves the added-mass cases in full")
    ap.add_argument("--effect", choices=EFFECTS + ["clean"],
                    help="a focused calibration set: every case has this effect (or none); "
                         "blind runs leave it unset")
    ap.add_argument("--object", choices=list(OBJECTS),
                    help="a focused calibration set: every case on this object")
    a = ap.parse_args()
    BIN = os.path.abspath(a.bin)
    PROBE = os.path.abspath(a.probe)
    ONLY_OBJECT = a.object
    os.makedirs(os.path.join(a.out, "labels"), exist_ok=True)
    work = os.path.join(a.out, "objects")
    os.makedirs(work, exist_ok=True)
    rng = np.random.default_rng(a.seed)
    # A third of the cases are controls (clean or told a wrong E); the rest cycle the effects.
    plan = []
    for i in range(a.cases):
        if i % 3 == 0:
            plan.append((None, "uniform_shift" if (i // 3) % 2 else "clean"))
        else:
            plan.append((EFFECTS[(i - i // 3 - 1) % len(EFFECTS)], None))
    if a.effect is not None:
        plan = [(None, "clean") if a.effect == "clean" else (a.effect, None)] * a.cases
    order = rng.permutation(a.cases)
    for idx, j in enumerate(order):
        effect, control = plan[j]
        info = make_case(idx, rng, effect, control, work, a.out, a.np)
        print(f"case_{idx:03d}: {info}", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
