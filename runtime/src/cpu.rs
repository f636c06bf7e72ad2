//! What the machine gives a run besides its file: the instruction sets
//! sdfl's own kernels may use, and the memory its libraries keep per
//! thread.
//!
//! The kernels read [`kernels`] once a process. `SDFL_KERNELS` caps the
//! widest set they take: `portable` (no SIMD beyond the baseline build),
//! `avx2`, `avx512`, or `native` (unset: all the CPU has). A CPU without
//! the named set keeps what it has. So one machine runs every path its CPU
//! allows, as a machine without AVX-512 would: the test suite runs once
//! natively and once with `SDFL_KERNELS=portable` (`.ci/run`). The matrix
//! libraries (matrixmultiply, and gemm behind dfdx) pick their own kernels
//! and are not capped.

use std::sync::OnceLock;

/// The widest instruction set a kernel may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    /// The baseline build: portable code only.
    Portable,
    /// AVX2 (and FMA-free 8-lane code).
    Avx2,
    /// AVX-512 F (16 lanes), with BF16 products where the CPU has them.
    Avx512,
}

impl Level {
    /// `SDFL_KERNELS`'s value as a cap (`native` and unset: none).
    pub fn parse(s: &str) -> Option<Option<Level>> {
        match s.trim().to_ascii_lowercase().as_str() {
            "" | "native" => Some(None),
            "portable" => Some(Some(Level::Portable)),
            "avx2" => Some(Some(Level::Avx2)),
            "avx512" => Some(Some(Level::Avx512)),
            _ => None,
        }
    }
}

/// The instruction sets sdfl's kernels use on this CPU, after the cap.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Kernels {
    /// 8-lane AVX2 code.
    pub avx2: bool,
    /// 16-lane AVX-512 F code.
    pub avx512f: bool,
    /// `vdpbf16ps` products (AVX-512 BF16).
    pub avx512bf16: bool,
    /// The cap `SDFL_KERNELS` set, if any.
    pub cap: Option<Level>,
}

impl Kernels {
    /// What a CPU with these sets runs under `cap`.
    pub fn capped(avx2: bool, avx512f: bool, avx512bf16: bool, cap: Option<Level>) -> Kernels {
        let allow = |l: Level| cap.is_none_or(|c| l <= c);
        let avx512f = avx512f && allow(Level::Avx512);
        Kernels {
            avx2: avx2 && allow(Level::Avx2),
            avx512f,
            avx512bf16: avx512f && avx512bf16,
            cap,
        }
    }

    /// The widest set in use.
    pub fn level(&self) -> Level {
        if self.avx512f {
            Level::Avx512
        } else if self.avx2 {
            Level::Avx2
        } else {
            Level::Portable
        }
    }

    /// One line for logs and reports: `avx512 (bf16)`, `avx2 (capped by
    /// SDFL_KERNELS)`.
    pub fn describe(&self) -> String {
        let mut s = match self.level() {
            Level::Avx512 => "avx512".to_string(),
            Level::Avx2 => "avx2".to_string(),
            Level::Portable => "portable".to_string(),
        };
        if self.avx512bf16 {
            s += " (bf16)";
        }
        if self.cap.is_some() {
            s += " (capped by SDFL_KERNELS)";
        }
        s
    }

    fn detect() -> Kernels {
        let raw = std::env::var("SDFL_KERNELS").unwrap_or_default();
        let cap = Level::parse(&raw).unwrap_or_else(|| {
            eprintln!(
                "warning: SDFL_KERNELS={raw:?} is not one of portable, avx2, avx512, native: using native"
            );
            None
        });
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            Kernels::capped(
                has!("avx2"),
                has!("avx512f"),
                has!("avx512f") && has!("avx512bf16"),
                cap,
            )
        }
        #[cfg(target_arch = "x86")]
        {
            Kernels::capped(
                std::arch::is_x86_feature_detected!("avx2"),
                false,
                false,
                cap,
            )
        }
        #[cfg(not(any(target_arch = "x86_64", target_arch = "x86")))]
        {
            Kernels::capped(false, false, false, cap)
        }
    }
}

static KERNELS: OnceLock<Kernels> = OnceLock::new();

/// The kernels this process runs (read once).
#[inline]
pub fn kernels() -> &'static Kernels {
    KERNELS.get_or_init(Kernels::detect)
}

/// What a run's memory depends on besides its file, on this machine: the
/// threads that may compute at once (the pool's workers and the thread
/// that called them) and the scratch the matrix library behind the dfdx
/// graph keeps in each (gemm's per-thread buffer is the size of the core's
/// L2 cache: 1 MiB on a Zen 4 EPYC, 2 MiB on a Sapphire Rapids Xeon).
pub fn host() -> sdfl_stdlib::work::Host {
    sdfl_stdlib::work::Host {
        threads: rayon::current_num_threads() + 1,
        matmul_scratch: gemm_common::cache::CACHE_INFO[1].cache_bytes as f64
            // The buffer's alignment slack (a cache line).
            + 64.0,
    }
}
