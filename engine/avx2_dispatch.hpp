#pragma once
// Byte loops compiled twice, for the baseline (SSE2) and for AVX2 (twice as wide), the AVX2 copy
// called where the processor has it. Explicit dispatch rather than GCC's target_clones: an
// ifunc resolver runs before the sanitizers' runtimes start, and crashes ThreadSanitizer builds.
//
//   SLAM_AVX2_BODY void FooBody(args) { ... }   // the loops, always inlined
//   SLAM_AVX2_COPY void FooAvx2(args) { FooBody(args); }
//   void Foo(args) { if (SLAM_AVX2_AVAILABLE()) return FooAvx2(args); FooBody(args); }

#include "engine/ray_cast_wide.hpp"

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define SLAM_AVX2_BODY [[gnu::always_inline]] inline
#define SLAM_AVX2_COPY [[gnu::target("avx2")]]
#define SLAM_AVX2_AVAILABLE() ::slam::wide::Avx2Supported()
#else
#define SLAM_AVX2_BODY inline
#define SLAM_AVX2_COPY
#define SLAM_AVX2_AVAILABLE() false
#endif
