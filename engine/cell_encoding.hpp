#pragma once
// The one place that owns how a cell stores its occupancy: log odds as a clamped 16-bit integer.

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace slam {

/// Log odds of occupancy, scaled by kLogOddsScale; 0 = unknown (p = 0.5).
using LogOdds = int16_t;

inline constexpr double kLogOddsScale = 1000.0;  // 1 unit = 0.001 in natural log odds
inline constexpr int kLogOddsLimit = 16000;      // |l| <= 16 (p in [1e-7, 1 - 1e-7])

/// Encodes a natural log-odds value (clamped).
inline LogOdds EncodeLogOdds(double l) {
  const double scaled =
      std::clamp(l * kLogOddsScale, -double{kLogOddsLimit}, double{kLogOddsLimit});
  return static_cast<LogOdds>(std::lround(scaled));
}

/// Decodes a cell to natural log odds.
inline double DecodeLogOdds(LogOdds v) { return v / kLogOddsScale; }

/// Probability of occupancy of an encoded cell.
inline double OccupancyProbability(LogOdds v) { return 1.0 / (1.0 + std::exp(-DecodeLogOdds(v))); }

/// Adds an update to a cell, clamping to the representable range.
inline LogOdds AddLogOdds(LogOdds cell, int delta, int limit) {
  return static_cast<LogOdds>(std::clamp(int{cell} + delta, -limit, limit));
}

}  // namespace slam
