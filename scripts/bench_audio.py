#!/usr/bin/env python3
"""Time of one loss-plus-gradient evaluation in diffsound against PyTorch (CPU, autograd, float64).

The problem: a seeded random bank of 256 damped sinusoids (frequencies log-uniform in
[60, 16000] Hz, decay rates in [1, 40] 1/s, random amplitudes and phases) rendered for 1 s at
48 kHz is the target; a perturbed copy (frequencies off by up to ±3 %, decays, amplitudes and
phases perturbed too) is the prediction. For each loss (the multi-scale spectral loss and the
frame-wise 1-D transport loss, both with the crate's default settings) one evaluation is

    render the prediction -> loss value and dL/ds -> dL/d(frequency, decay, amplitude, phase)

and both sides time exactly that (the target's spectrograms are prepared once, outside the
loop; one untimed warm-up precedes the timed repeats). diffsound runs
`examples/bench_audio_loss.rs` (built with `cargo build --release --example bench_audio_loss`);
PyTorch computes the same formulas directly:

    s[n] = sum_k a_k exp(-d_k n/fs) sin(2 pi f_k n/fs + phi_k)      (vectorised over modes)
    S    = |torch.stft(F.pad(s, (N/2, N/2)), N, N/4, hann_window(N, periodic), center=False)|
    spectral:  sum_N mean|S - S_y| + mean|ln(S + e_N) - ln(S_y + e_N)|, e_N = 1e-4 max S_y, N = 2048 ... 64
    transport: sum_t w_t * fs/N * sum_{k<K-1} |P_k - Q_k|  (see src/audio/loss.rs), N = 2048

with .backward() for the gradients. It prints, per loss, the median and min time of each side,
the ratio torch/diffsound, the relative difference of the loss values and, per parameter, the
max |g_rust - g_torch| / max |g_torch|. The two synthesisers differ in floating point (complex
recursion re-anchored every 1024 samples vs direct sin/exp, ~1e-13 of the peak), so agreement
is expected to round-off level, not bit equality. Measures only; asserts nothing about time.

A second, untimed table (first configuration only) splits the gradient difference by where it
arises, with diffsound's intermediate signals (DIFFSOUND_BENCH_DUMP) and diffsound's target:
  synth        max |s_rust - s_torch| / max |s| for the prediction;
  loss_value   torch's loss of diffsound's signal vs diffsound's value;
  via_signal   torch end to end with diffsound's signal swapped in for the forward value;
  via_loss     torch's synthesis backward of diffsound's dL/ds vs of torch's dL/ds, same signal;
  via_backward render_backward vs torch's synthesis backward, same dL/ds;
  ulp          torch's own gradients with its signal scaled by 1 + eps*r, r in {-1, 0, 1}.
(worst parameter, relative to that gradient's max abs.) The spectral loss's log term weighs bins
by 1/(S + 1e-7), and bins far above the highest partial have S ~ 1e-10, so its gradients move by
~1e-10 relative per ulp of change in the signal; the two syntheses differ by ~1e-13 of the peak
(~1e3 ulp), which is what moves the spectral gradients by ~1e-7 ("via_signal"). The transport
loss is far less sensitive.

It runs twice: with diffsound's default thread count (the machine's parallelism, or
DIFFSOUND_THREADS) and torch.set_num_threads set to the same count, then with one thread each.

PyTorch comes from a virtualenv (default ~/.cache/diffsound-bench-venv, or $DIFFSOUND_BENCH_VENV),
created with `pip install torch numpy` when missing; the script re-executes itself under the
venv's python if torch cannot be imported.

    python3 scripts/bench_audio.py                       # 7 repeats, summary in target/bench_audio.json
    python3 scripts/bench_audio.py --repeats 15 --seed 3 --out /tmp/bench.json
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VENV = Path(os.environ.get("DIFFSOUND_BENCH_VENV", Path.home() / ".cache" / "diffsound-bench-venv"))


def ensure_torch():
    """Import torch and numpy, or re-execute this script under the benchmark venv (creating it)."""
    try:
        import numpy  # noqa: F401
        import torch  # noqa: F401
        return
    except ImportError:
        pass
    if os.environ.get("DIFFSOUND_BENCH_REEXEC"):
        sys.exit(f"torch/numpy still not importable under {sys.executable}")
    python = VENV / "bin" / "python"
    if not python.exists():
        print(f"creating {VENV} and installing torch, numpy from PyPI", flush=True)
        subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True)
        subprocess.run([str(python), "-m", "pip", "install", "torch", "numpy"], check=True)
    else:
        probe = subprocess.run([str(python), "-c", "import torch, numpy"], capture_output=True)
        if probe.returncode != 0:
            subprocess.run([str(python), "-m", "pip", "install", "torch", "numpy"], check=True)
    env = dict(os.environ, DIFFSOUND_BENCH_REEXEC="1")
    os.execve(str(python), [str(python), str(Path(__file__).resolve()), *sys.argv[1:]], env)


ensure_torch()
import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402

SPECTRAL_FFT_SIZES = (2048, 1024, 512, 256, 128, 64)
LOG_EPSILON_RELATIVE = 1e-4
TRANSPORT_FFT = 2048
TRANSPORT_RELATIVE_FLOOR = 1e-9
HOP_FRACTION = 0.25
PARAMS = ("frequencies_hz", "decay_rates", "amplitudes", "phases")


def make_problem(n_modes, sample_rate, n_samples, seed):
    rng = np.random.default_rng(seed)
    f = np.exp(rng.uniform(np.log(60.0), np.log(16000.0), n_modes))
    d = rng.uniform(1.0, 40.0, n_modes)
    # Roughly -40 ... 0 dB, scaled so the target's peak is of order 1 (as the fits scale recordings).
    a = 10.0 ** rng.uniform(-2.0, 0.0, n_modes) / np.sqrt(n_modes)
    phi = rng.uniform(0.0, 2.0 * np.pi, n_modes)
    target = {"frequencies_hz": f, "decay_rates": d, "amplitudes": a, "phases": phi}
    prediction = {
        "frequencies_hz": f * (1.0 + rng.uniform(-0.03, 0.03, n_modes)),
        "decay_rates": d * (1.0 + rng.uniform(-0.3, 0.3, n_modes)),
        "amplitudes": a * (1.0 + rng.uniform(-0.3, 0.3, n_modes)),
        "phases": phi + rng.uniform(-0.5, 0.5, n_modes),
    }
    as_lists = lambda b: {k: v.tolist() for k, v in b.items()}  # noqa: E731
    return {"sample_rate": sample_rate, "n_samples": n_samples, "target": as_lists(target), "prediction": as_lists(prediction)}


# ---------------------------------------------------------------- PyTorch reference


def synth(f, d, a, phi, sample_rate, n_samples):
    t = torch.arange(n_samples, dtype=torch.float64) / sample_rate
    # (modes, samples); 256 x 48000 doubles is ~100 MB per intermediate, fine on this machine.
    env = torch.exp(-d[:, None] * t[None, :])
    osc = torch.sin(2.0 * torch.pi * f[:, None] * t[None, :] + phi[:, None])
    return (a[:, None] * env * osc).sum(0)


def spectrogram(x, n_fft):
    hop = round(n_fft * HOP_FRACTION)
    window = torch.hann_window(n_fft, periodic=True, dtype=torch.float64)
    padded = F.pad(x[None, :], (n_fft // 2, n_fft // 2))[0]
    return torch.stft(padded, n_fft, hop, window=window, center=False, return_complex=True).abs().T  # frames x bins


class TorchSpectral:
    def __init__(self, target):
        self.targets = {n: spectrogram(target, n) for n in SPECTRAL_FFT_SIZES}

    def __call__(self, x):
        total = 0.0
        for n, sy in self.targets.items():
            s = spectrogram(x, n)
            eps = LOG_EPSILON_RELATIVE * sy.max()
            total = total + (s - sy).abs().mean() + (torch.log(s + eps) - torch.log(sy + eps)).abs().mean()
        return total


class TorchTransport:
    def __init__(self, target, sample_rate):
        sy = spectrogram(target, TRANSPORT_FFT)
        n_frames = sy.shape[0]
        hop = round(TRANSPORT_FFT * HOP_FRACTION)
        peak = sy.max(dim=1).values
        floor = TRANSPORT_RELATIVE_FLOOR * torch.where(peak > 0, peak, sy.max())
        q = (sy + floor[:, None]) / (sy + floor[:, None]).sum(1, keepdim=True)
        start = torch.arange(n_frames) * hop - TRANSPORT_FFT // 2
        inside = (start >= 0) & (start + TRANSPORT_FFT <= target.shape[0])
        w = torch.where(inside, sy.sum(1), torch.zeros(n_frames, dtype=torch.float64))
        self.weights = w / w.sum()
        self.floor = floor
        self.q_cdf = torch.cumsum(q, 1)
        self.bin_hz = sample_rate / TRANSPORT_FFT

    def __call__(self, x):
        s = spectrogram(x, TRANSPORT_FFT) + self.floor[:, None]
        p_cdf = torch.cumsum(s / s.sum(1, keepdim=True), 1)
        w_t = self.bin_hz * (p_cdf[:, :-1] - self.q_cdf[:, :-1]).abs().sum(1)
        return (self.weights * w_t).sum()


def torch_run(problem, loss_name, repeats, threads):
    torch.set_num_threads(threads)
    rate, n = problem["sample_rate"], problem["n_samples"]
    tb = {k: torch.tensor(v, dtype=torch.float64) for k, v in problem["target"].items()}
    with torch.no_grad():
        target = synth(tb["frequencies_hz"], tb["decay_rates"], tb["amplitudes"], tb["phases"], rate, n)
        loss = TorchSpectral(target) if loss_name == "spectral" else TorchTransport(target, rate)

    def evaluate():
        """One evaluation, cut at the signal (detach, then backward of dL/ds into the synthesis)
        only to time the three stages as diffsound reports them; the arithmetic is unchanged."""
        t0 = time.perf_counter()
        p = {k: torch.tensor(v, dtype=torch.float64, requires_grad=True) for k, v in problem["prediction"].items()}
        x = synth(p["frequencies_hz"], p["decay_rates"], p["amplitudes"], p["phases"], rate, n)
        t1 = time.perf_counter()
        xd = x.detach().requires_grad_(True)
        value = loss(xd)
        value.backward()
        t2 = time.perf_counter()
        x.backward(xd.grad)
        t3 = time.perf_counter()
        return value.item(), {k: p[k].grad.numpy() for k in PARAMS}, [1e3 * (t1 - t0), 1e3 * (t2 - t1), 1e3 * (t3 - t2)]

    value, grads, _ = evaluate()  # warm-up, and the reported result
    stages_ms = np.array([evaluate()[2] for _ in range(repeats)])
    times = stages_ms.sum(1)
    return {"value": value, "gradient": grads, "threads": torch.get_num_threads(),
            "time_ms": {"median": float(np.median(times)), "min": float(np.min(times)), "all": times.tolist(),
                        **{f"{s}_median": float(np.median(stages_ms[:, i])) for i, s in enumerate(("render", "loss", "backward"))}}}


def max_rel(a, b):
    """max |a - b| / max |b|."""
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(np.asarray(b))))


def stages(problem, loss_name, rust, dump):
    """Untimed diagnostics: splits the end-to-end gradient difference by where it arises, using
    diffsound's intermediate signals, and measures how far torch's own result moves under a
    1-ulp change of the signal (the conditioning of the comparison)."""
    rate, n = problem["sample_rate"], problem["n_samples"]
    y_r, x_r, g_r = (torch.from_numpy(np.fromfile(Path(dump) / f"{k}.f64")) for k in ("target", "signal", "grad_signal"))
    loss = TorchSpectral(y_r) if loss_name == "spectral" else TorchTransport(y_r, rate)

    def torch_grads(signal=None, grad_signal=None, scale=None):
        """Torch end to end on diffsound's target; optionally with diffsound's signal swapped in
        for the forward value (straight through), with diffsound's dL/ds, or with the signal scaled."""
        p = {k: torch.tensor(v, dtype=torch.float64, requires_grad=True) for k, v in problem["prediction"].items()}
        x = synth(p["frequencies_hz"], p["decay_rates"], p["amplitudes"], p["phases"], rate, n)
        if grad_signal is not None:
            x.backward(grad_signal)
        else:
            if signal is not None:
                x = x + (signal - x).detach()
            if scale is not None:
                x = x * scale
            loss(x).backward()
        return {k: p[k].grad.numpy() for k in PARAMS}

    def worst(a, b):
        return max(max_rel(a[k], b[k]) for k in PARAMS)

    base = torch_grads()
    on_rust_signal = torch_grads(signal=x_r)
    on_rust_dlds = torch_grads(grad_signal=g_r)
    r = torch.from_numpy(np.random.default_rng(0).choice([-1.0, 0.0, 1.0], n)) * np.finfo(np.float64).eps
    with torch.no_grad():
        value = loss(x_r).item()
    return {
        "synth": max_rel(x_r, synth(*(torch.tensor(problem["prediction"][k], dtype=torch.float64) for k in PARAMS), rate, n)),
        "loss_value": abs(value - rust["value"]) / abs(value),
        "via_signal": worst(on_rust_signal, base),
        "via_loss": worst(on_rust_dlds, on_rust_signal),
        "via_backward": worst(rust["gradient"], on_rust_dlds),
        "ulp": worst(torch_grads(scale=1.0 + r), base),
    }


# ---------------------------------------------------------------- diffsound


def rust_binary():
    print("building: cargo build --release --example bench_audio_loss", flush=True)
    subprocess.run(["cargo", "build", "--release", "--example", "bench_audio_loss"], cwd=ROOT, check=True)
    return ROOT / "target" / "release" / "examples" / "bench_audio_loss"


def rust_run(binary, problem, loss_name, repeats, threads, workdir):
    job = dict(problem, loss=loss_name, repeats=repeats)
    src = Path(workdir) / f"problem_{loss_name}.json"
    dst = Path(workdir) / f"result_{loss_name}.json"
    src.write_text(json.dumps(job))
    cmd = [str(binary), str(src), str(dst)] + ([str(threads)] if threads else [])
    # The dump (intermediate signals for `stages`) is written before the timed loop.
    env = dict(os.environ, DIFFSOUND_BENCH_DUMP=str(Path(workdir) / f"dump_{loss_name}"))
    subprocess.run(cmd, check=True, stderr=subprocess.DEVNULL, env=env)
    r = json.loads(dst.read_text())
    r["gradient"] = {k: np.asarray(v) for k, v in r["gradient"].items()}
    return r


# ---------------------------------------------------------------- comparison


def compare(rust, ref):
    out = {"value_rel_diff": abs(rust["value"] - ref["value"]) / abs(ref["value"])}
    for k in PARAMS:
        out[f"grad_{k}_rel_diff"] = max_rel(rust["gradient"][k], ref["gradient"][k])
    return out


def run_config(binary, problem, repeats, rust_threads, workdir, diagnose):
    """One row per loss; rust_threads None = diffsound's default, torch then uses the same count."""
    rows = []
    for loss_name in ("spectral", "transport"):
        rust = rust_run(binary, problem, loss_name, repeats, rust_threads, workdir)
        ref = torch_run(problem, loss_name, repeats, rust["threads"])
        row = {"loss": loss_name, "rust_threads": rust["threads"], "torch_threads": ref["threads"],
               "rust_ms": rust["time_ms"], "torch_ms": ref["time_ms"],
               "ratio_torch_over_rust": ref["time_ms"]["median"] / rust["time_ms"]["median"],
               "rust_value": rust["value"], "torch_value": ref["value"], "rust_deterministic": rust["deterministic"]}
        row.update(compare(rust, ref))
        if diagnose:
            row["stages"] = stages(problem, loss_name, rust, Path(workdir) / f"dump_{loss_name}")
        rows.append(row)
    return rows


def print_table(rows):
    r0 = rows[0]
    print(f"\nthreads: diffsound {r0['rust_threads']}, torch {r0['torch_threads']}")
    head = (f"{'loss':<10}{'rust med/min ms':>18}{'torch med/min ms':>19}{'torch/rust':>11}{'value rel':>11}"
            f"{'d freq':>10}{'d decay':>10}{'d amp':>10}{'d phase':>10}")
    print(head)
    for r in rows:
        rust = f"{r['rust_ms']['median']:.1f}/{r['rust_ms']['min']:.1f}"
        ref = f"{r['torch_ms']['median']:.1f}/{r['torch_ms']['min']:.1f}"
        print(f"{r['loss']:<10}{rust:>18}{ref:>19}{r['ratio_torch_over_rust']:>11.1f}{r['value_rel_diff']:>11.1e}"
              + "".join(f"{r[f'grad_{k}_rel_diff']:>10.1e}" for k in PARAMS))
        stage = lambda t: "/".join(f"{t[f'{s}_median']:.1f}" for s in ("render", "loss", "backward"))  # noqa: E731
        print(f"{'':<10}values: diffsound {r['rust_value']:.15e}, torch {r['torch_value']:.15e}")
        print(f"{'':<10}median render/loss/backward ms: diffsound {stage(r['rust_ms'])}, torch {stage(r['torch_ms'])}")
    if any("stages" in r for r in rows):
        cols = ("synth", "loss_value", "via_signal", "via_loss", "via_backward", "ulp")
        print(f"\n{'stages':<10}" + "".join(f"{c:>13}" for c in cols) + "   (untimed; see --help)")
        for r in rows:
            print(f"{r['loss']:<10}" + "".join(f"{r['stages'][c]:>13.1e}" for c in cols))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--modes", type=int, default=256)
    ap.add_argument("--sample-rate", type=float, default=48000.0)
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--out", default=str(ROOT / "target" / "bench_audio.json"), help="JSON summary")
    args = ap.parse_args()
    print(f"torch {torch.__version__} ({sys.executable}), numpy {np.__version__}")
    n_samples = round(args.seconds * args.sample_rate)
    problem = make_problem(args.modes, args.sample_rate, n_samples, args.seed)
    print(f"{args.modes} modes, {n_samples} samples at {args.sample_rate:g} Hz, seed {args.seed}, {args.repeats} repeats")
    binary = rust_binary()
    load = os.getloadavg()
    print(f"load average before the runs: {load[0]:.2f} (1 min) on {os.cpu_count()} CPUs; timings are noisy if others run")
    summary = {"load_average_1min": load[0], "modes": args.modes, "n_samples": n_samples, "sample_rate": args.sample_rate, "seed": args.seed,
               "repeats": args.repeats, "torch_version": torch.__version__, "runs": []}
    with tempfile.TemporaryDirectory() as workdir:
        for threads in (None, 1):
            rows = run_config(binary, problem, args.repeats, threads, workdir, diagnose=threads is None)
            print_table(rows)
            summary["runs"].append(rows)
    print("\ntimes: one render -> loss value and gradient (dL/ds) -> backward to the modes; ratio = torch median / diffsound median")
    print("d <param>: max |g_rust - g_torch| / max |g_torch| over the modes")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(summary, indent=1))
    print(f"summary: {args.out}")


if __name__ == "__main__":
    main()
