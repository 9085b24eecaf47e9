#pragma once
// Small, portable, seedable random numbers: results depend only on the seed and the stream
// coordinates, never on thread count or library version (std:: distributions are not portable).

#include <cmath>
#include <cstdint>

namespace slam {

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

 private:
  static constexpr uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  uint64_t state_[4];
};

}  // namespace slam
