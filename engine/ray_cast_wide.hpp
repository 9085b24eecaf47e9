#pragma once
// The wide (SIMD) kernels of CastToObstacles(MatchWindow, ...), for match_window.cpp, which picks
// one at run time (WindowKernel): x86-64 only; elsewhere nothing is supported.

#include <vector>

#include "engine/grid_traversal.hpp"
#include "engine/match_window.hpp"

namespace slam::wide {

/// Whether this processor runs CastAvx512 (AVX-512F/VL, AVX2 and BMI2) / CastAvx2 (AVX2).
bool Avx512Supported();
bool Avx2Supported();

/// CastToObstacles(window, rays, hits) eight / four rays per instruction: the same answers as
/// the portable kernel, bit for bit. Precondition: the processor supports the kernel.
void CastAvx512(const MatchWindow& window, const std::vector<RayQuery>& rays,
                std::vector<RayHit>& hits);
void CastAvx2(const MatchWindow& window, const std::vector<RayQuery>& rays,
              std::vector<RayHit>& hits);

}  // namespace slam::wide
