fn main() {
    if let Some(missing) = missing_cpu_features() {
        eprintln!(
            "error: this diffsound was built for a CPU with {missing}, which this CPU lacks (the \
             repository's .cargo/config.toml builds for the building machine's CPU); rebuild it \
             here, or for any x86-64 with RUSTFLAGS=\"-C target-cpu=x86-64\" cargo build --release"
        );
        std::process::exit(1);
    }
    diffsound::cli::main();
}

/// The instruction sets this binary was compiled to use that the CPU running it lacks: a clear
/// error instead of an illegal instruction in the middle of an MPI job. The repository builds
/// for the building machine's CPU (`.cargo/config.toml`), and a binary copied to an older node
/// of a cluster would otherwise die there. The CPU is asked through CPUID itself:
/// `is_x86_feature_detected!` answers yes for every feature enabled at compile time.
fn missing_cpu_features() -> Option<String> {
    #[allow(unused_mut)]
    let mut missing: Vec<&str> = Vec::new();
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{__cpuid, __cpuid_count};
        // CPUID leaves 1 (ECX), 7.0 (EBX) and 0x8000_0001 (ECX), where the CPU has them.
        #[allow(unused_unsafe)]
        let (leaf1, leaf7, extended) = unsafe {
            let max = __cpuid(0).eax;
            let max_extended = __cpuid(0x8000_0000).eax;
            (
                __cpuid(1).ecx,
                if max >= 7 { __cpuid_count(7, 0).ebx } else { 0 },
                if max_extended >= 0x8000_0001 {
                    __cpuid(0x8000_0001).ecx
                } else {
                    0
                },
            )
        };
        // (name, compiled in, CPUID register, bit): each name written once.
        macro_rules! feature {
            ($name:tt, $register:expr, $bit:expr) => {
                ($name, cfg!(target_feature = $name), $register, $bit)
            };
        }
        let features: [(&str, bool, u32, u32); 17] = [
            feature!("sse3", leaf1, 0),
            feature!("ssse3", leaf1, 9),
            feature!("fma", leaf1, 12),
            feature!("sse4.1", leaf1, 19),
            feature!("sse4.2", leaf1, 20),
            feature!("popcnt", leaf1, 23),
            feature!("avx", leaf1, 28),
            feature!("f16c", leaf1, 29),
            feature!("bmi1", leaf7, 3),
            feature!("avx2", leaf7, 5),
            feature!("bmi2", leaf7, 8),
            feature!("avx512f", leaf7, 16),
            feature!("avx512dq", leaf7, 17),
            feature!("avx512cd", leaf7, 28),
            feature!("avx512bw", leaf7, 30),
            feature!("avx512vl", leaf7, 31),
            feature!("lzcnt", extended, 5),
        ];
        missing.extend(
            features
                .iter()
                .filter(|&&(_, compiled, register, bit)| compiled && register & (1 << bit) == 0)
                .map(|&(name, ..)| name),
        );
    }
    (!missing.is_empty()).then(|| missing.join(", "))
}
