//! The SIMD width cap: the variable's names and which instruction sets a
//! cap keeps.

use sdfl_runtime::cpu::*;

#[test]
fn the_cap_removes_wider_sets_and_keeps_narrower_ones() {
    let all = |cap| Kernels::capped(true, true, true, cap);
    assert_eq!(all(None).level(), Level::Avx512);
    assert!(all(None).avx512bf16);
    assert_eq!(all(Some(Level::Avx512)).level(), Level::Avx512);
    let k = all(Some(Level::Avx2));
    assert_eq!((k.level(), k.avx512bf16), (Level::Avx2, false));
    let k = all(Some(Level::Portable));
    assert_eq!((k.avx2, k.avx512f, k.avx512bf16), (false, false, false));
    // A cap above what the CPU has changes nothing; BF16 needs F.
    let k = Kernels::capped(true, false, true, Some(Level::Avx512));
    assert_eq!((k.level(), k.avx512bf16), (Level::Avx2, false));
}

#[test]
fn the_variable_names_the_caps() {
    assert_eq!(Level::parse("portable"), Some(Some(Level::Portable)));
    assert_eq!(Level::parse(" AVX2 "), Some(Some(Level::Avx2)));
    assert_eq!(Level::parse("avx512"), Some(Some(Level::Avx512)));
    assert_eq!(Level::parse("native"), Some(None));
    assert_eq!(Level::parse(""), Some(None));
    assert_eq!(Level::parse("sse9"), None);
}
