#pragma once
// Small, portable, seedable random numbers: results depend only on the seed and the stream
// coordinates, never on thread count or library version (std:: distributions are not portable).

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>

namespace slam {

/// The ziggurat of the standard normal density f(x) = exp(-x^2/2) (Marsaglia and Tsang 2000, in
/// Doornik's 2005 form): 128 layers of equal area, layer i spanning [0, x[i]] between heights
/// f(x[i]) and f(x[i + 1]); the bottom layer, a rectangle of width x[0] = kArea / f(kR), holds
/// the tail beyond kR.
struct ZigguratTables {
  static constexpr size_t kLayers = 128;
  static constexpr double kR = 3.442619855899;          // where the tail begins
  static constexpr double kArea = 9.91256303526217e-3;  // of each layer
  std::array<double, kLayers + 1> x{};                  // x[1] = kR > x[2] > ... > x[kLayers] = 0
  std::array<double, kLayers> ratio{};  // x[i + 1] / x[i]: below it, layer i is under f

  ZigguratTables() {
    double f = std::exp(-0.5 * kR * kR);
    x[0] = kArea / f;
    x[1] = kR;
    for (size_t i = 2; i < kLayers; ++i) {
      x[i] = std::sqrt(-2.0 * std::log(kArea / x[i - 1] + f));
      f = std::exp(-0.5 * x[i] * x[i]);
    }
    x[kLayers] = 0.0;
    for (size_t i = 0; i < kLayers; ++i) ratio[i] = x[i + 1] / x[i];
  }
};

/// The one set of ziggurat tables (built on first use).
inline const ZigguratTables& Ziggurat() {
  static const ZigguratTables tables;
  return tables;
}

/// SplitMix64 step: a good 64-bit mixer used to derive independent streams.
constexpr uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

/// xoshiro256** generator with Gaussian and uniform draws.
class Rng {
 public:
  explicit Rng(uint64_t seed) {
    uint64_t s = seed;
    for (auto& word : state_) word = s = SplitMix64(s);
  }

  /// A generator for stream (a, b, c) of `seed`; distinct coordinates give independent streams.
  static Rng ForStream(uint64_t seed, uint64_t a, uint64_t b = 0, uint64_t c = 0) {
    return Rng(SplitMix64(SplitMix64(SplitMix64(seed ^ SplitMix64(a)) ^ b) ^ c));
  }

  uint64_t Next() {
    const uint64_t result = Rotl(state_[1] * 5, 7) * 9;
    const uint64_t t = state_[1] << 17;
    state_[2] ^= state_[0];
    state_[3] ^= state_[1];
    state_[1] ^= state_[2];
    state_[0] ^= state_[3];
    state_[2] ^= t;
    state_[3] = Rotl(state_[3], 45);
    return result;
  }

  /// Uniform in [0, 1).
  double Uniform() { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }

  /// Standard normal draw (Box-Muller; one value per call for simple reproducibility).
  double Gaussian() {
    const double u1 = 1.0 - Uniform();  // (0, 1]
    const double u2 = Uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * 3.14159265358979323846 * u2);
  }

  /// Normal draw with the given standard deviation.
  double Gaussian(double sigma) { return sigma * Gaussian(); }

  /// Standard normal draw by the ziggurat (ZigguratTables): one 64-bit draw, a table lookup and
  /// a product 99 % of the time; no logarithm or cosine as Box-Muller needs. A different
  /// sequence from Gaussian()'s for the same generator: the simulator keeps Gaussian(), so that
  /// the experiments it generates from a seed stay the same.
  double Normal() {
    const ZigguratTables& z = Ziggurat();
    for (;;) {
      const uint64_t bits = Next();
      const double u = static_cast<double>(bits >> 11) * 0x1.0p-52 - 1.0;        // [-1, 1)
      const auto i = static_cast<size_t>(bits & (ZigguratTables::kLayers - 1));  // other bits
      if (std::fabs(u) < z.ratio[i]) return u * z.x[i];
      if (i == 0) return NormalTail(u < 0.0);
      // The wedge of layer i beyond x[i + 1]: accept x where a uniform height in the layer falls
      // under f(x); heights relative to f(x).
      const double x = u * z.x[i];
      const double below = std::exp(-0.5 * (z.x[i] * z.x[i] - x * x));          // f(x[i]) / f(x)
      const double above = std::exp(-0.5 * (z.x[i + 1] * z.x[i + 1] - x * x));  // f(x[i+1]) / f(x)
      if (below + Uniform() * (above - below) < 1.0) return x;
    }
  }

  /// Normal draw with the given standard deviation, by the ziggurat (Normal()).
  double Normal(double sigma) { return sigma * Normal(); }

 private:
  static constexpr uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

  // The normal's tail beyond ZigguratTables::kR (Marsaglia 1964), negative if asked.
  double NormalTail(bool negative) {
    constexpr double r = ZigguratTables::kR;
    double x = 0.0, y = 0.0;
    do {
      x = -std::log(1.0 - Uniform()) / r;  // 1 - Uniform() is in (0, 1]
      y = -std::log(1.0 - Uniform());
    } while (y + y < x * x);
    return negative ? -(r + x) : r + x;
  }

  uint64_t state_[4];
};

}  // namespace slam
