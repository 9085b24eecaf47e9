#pragma once

/// SLAM_TARGET_CLONES before a function compiles it twice, for x86-64-v3 (AVX2) and for the
/// baseline, and calls the one the processor runs, chosen once at load time (GNU ifunc). For
/// byte-wise loops that vectorise: their answers do not depend on the clone. x86-64-v4 is left
/// out: its 512-bit byte loops measured slower than AVX2's here (BM_MatchWindowBuild: 500
/// against 650 M cells/s, baseline 580).
#if defined(__x86_64__) && defined(__GNUC__) && defined(__ELF__) && !defined(__APPLE__)
#define SLAM_TARGET_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define SLAM_TARGET_CLONES
#endif
