#pragma once
// Inline replacements for libm calls on the engine's hot paths, where the arguments are known to
// lie in a narrow range: a call each costs about as much as the work around it. Deterministic
// (plain IEEE arithmetic; the engine is built without floating-point contraction), within a few
// units in the last place of libm's answers (docs/performance.md, "Around the rays").

#include <cmath>
#include <cstddef>
#include <iterator>
#include <utility>

namespace slam {

/// Turns up to this size (radians) are SmallTurn's domain.
inline constexpr double kSmallTurnRad = 0.5;

/// {cos(a), sin(a)} for |a| <= kSmallTurnRad by their Taylor series, whose first omitted terms
/// are below 1e-16 there: a candidate's correction turning a sample's nominal heading.
inline std::pair<double, double> SmallTurn(double a) {
  const double a2 = a * a;
  // Horner over a^2: the reciprocal factorials 1/14!, 1/12!, ..., 1/0! and 1/13!, ..., 1/1!.
  constexpr double kCos[] = {1.0 / 87178291200.0, 1.0 / 479001600.0, 1.0 / 3628800.0, 1.0 / 40320.0,
                             1.0 / 720.0,         1.0 / 24.0,        1.0 / 2.0,       1.0};
  constexpr double kSin[] = {1.0 / 6227020800.0,
                             1.0 / 39916800.0,
                             1.0 / 362880.0,
                             1.0 / 5040.0,
                             1.0 / 120.0,
                             1.0 / 6.0,
                             1.0};
  double c = kCos[0], s = kSin[0];
  for (size_t k = 1; k < std::size(kCos); ++k) c = kCos[k] - c * a2;
  for (size_t k = 1; k < std::size(kSin); ++k) s = kSin[k] - s * a2;
  return {c, s * a};
}

}  // namespace slam
