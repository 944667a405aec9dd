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
        let has = |register: u32, bit: u32| register & (1 << bit) != 0;
        let features = [
            ("sse3", cfg!(target_feature = "sse3"), has(leaf1, 0)),
            ("ssse3", cfg!(target_feature = "ssse3"), has(leaf1, 9)),
            ("fma", cfg!(target_feature = "fma"), has(leaf1, 12)),
            ("sse4.1", cfg!(target_feature = "sse4.1"), has(leaf1, 19)),
            ("sse4.2", cfg!(target_feature = "sse4.2"), has(leaf1, 20)),
            ("popcnt", cfg!(target_feature = "popcnt"), has(leaf1, 23)),
            ("avx", cfg!(target_feature = "avx"), has(leaf1, 28)),
            ("f16c", cfg!(target_feature = "f16c"), has(leaf1, 29)),
            ("bmi1", cfg!(target_feature = "bmi1"), has(leaf7, 3)),
            ("avx2", cfg!(target_feature = "avx2"), has(leaf7, 5)),
            ("bmi2", cfg!(target_feature = "bmi2"), has(leaf7, 8)),
            ("avx512f", cfg!(target_feature = "avx512f"), has(leaf7, 16)),
            (
                "avx512dq",
                cfg!(target_feature = "avx512dq"),
                has(leaf7, 17),
            ),
            (
                "avx512cd",
                cfg!(target_feature = "avx512cd"),
                has(leaf7, 28),
            ),
            (
                "avx512bw",
                cfg!(target_feature = "avx512bw"),
                has(leaf7, 30),
            ),
            (
                "avx512vl",
                cfg!(target_feature = "avx512vl"),
                has(leaf7, 31),
            ),
            ("lzcnt", cfg!(target_feature = "lzcnt"), has(extended, 5)),
        ];
        missing.extend(
            features
                .iter()
                .filter(|(_, compiled, present)| *compiled && !present)
                .map(|(name, _, _)| *name),
        );
    }
    (!missing.is_empty()).then(|| missing.join(", "))
}
