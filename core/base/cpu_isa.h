// Which x86 instruction sets the kernels chosen at run time may use: the CPU's best, capped by
// $DHR_MAX_ISA (sse2, sse4.2, avx, avx2 or avx512; unset or empty: no cap). The cap applies to
// Embree's kernels (core/trace/rt_scene.h: their answers on rays that graze an edge differ between
// ISAs, so figures do too) and to dhrbench's own (the tracer's, svgf_ao's, FLIP's, the
// composite's, reprojection's, CRC-32C's; every width gives the same bits, which the tests check
// by running under the cap: tests/CMakeLists.txt). An AVX-512 machine with DHR_MAX_ISA=avx2 thus
// runs an AVX2 machine's path. (Functions built with GCC's target_clones, DHR_VEC8_TARGETS, pick
// their clone when the program loads and are not capped; they give the same bits either way.)
#pragma once

namespace dhr {

enum class Isa { kSse2, kSse42, kAvx, kAvx2, kAvx512 };

// "sse2", "sse4.2", "avx", "avx2", "avx512".
const char* isa_name(Isa isa);

// The best ISA this CPU has (for AVX-512: F, CD, DQ, BW and VL, as Embree's kernels need),
// capped by $DHR_MAX_ISA, read at each call. Throws dhr::Error naming the variable and the valid
// names when it holds anything else.
Isa usable_isa();

// Whether $DHR_MAX_ISA is set (and not empty): Embree is then given usable_isa() as its max_isa
// (core/trace/rt_scene.cpp); otherwise Embree makes its own choice.
bool isa_capped();

// Whether dhrbench's own kernels may use `isa` (the cap only; the caller checks the CPU). The
// cap is $DHR_MAX_ISA as the process started, for the whole process (kernels are chosen per
// call, often per row): setting the variable later caps Embree's next RtScene, not these.
// Throws dhr::Error, as usable_isa() does, at the first call when that value is not valid.
bool kernels_may_use(Isa isa);

}  // namespace dhr
