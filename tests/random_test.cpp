// The generator's normal draws: the ziggurat's tables against the normal density, and its draws
// against the normal distribution (seeded, so each check is deterministic).
#include "engine/random.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

namespace slam {
namespace {

double Density(double x) { return std::exp(-0.5 * x * x); }  // unnormalised, as the tables'
double NormalCdf(double x) { return 0.5 * std::erfc(-x / std::numbers::sqrt2); }

TEST(ZigguratTest, EveryLayerHasTheSameAreaUnderTheDensity) {
  const ZigguratTables& z = Ziggurat();
  constexpr size_t n = ZigguratTables::kLayers;
  const double area = ZigguratTables::kArea;
  EXPECT_EQ(z.x[1], ZigguratTables::kR);
  EXPECT_EQ(z.x[n], 0.0);
  for (size_t i = 1; i < n; ++i) EXPECT_GT(z.x[i], z.x[i + 1]) << i;
  // The bottom layer: the rectangle under f(kR) up to kR, and the tail beyond it.
  const double r = ZigguratTables::kR;
  const double tail = std::sqrt(std::numbers::pi / 2.0) * std::erfc(r / std::numbers::sqrt2);
  EXPECT_NEAR((r * Density(r) + tail) / area, 1.0, 1e-9);
  EXPECT_NEAR(z.x[0] * Density(r) / area, 1.0, 1e-12);
  // Layers 1 to n - 1: x[i] wide between heights f(x[i]) and f(x[i + 1]); the top one (the
  // recursion's last step, not forced) closes at height 1, as far as the constants' 13 digits
  // allow.
  for (size_t i = 1; i < n - 1; ++i) {
    EXPECT_NEAR(z.x[i] * (Density(z.x[i + 1]) - Density(z.x[i])) / area, 1.0, 1e-9) << i;
  }
  EXPECT_NEAR(z.x[n - 1] * (1.0 - Density(z.x[n - 1])) / area, 1.0, 1e-8);
  for (size_t i = 0; i < n; ++i) EXPECT_EQ(z.ratio[i], z.x[i + 1] / z.x[i]) << i;
}

TEST(ZigguratTest, DrawsFollowTheStandardNormal) {
  Rng rng(20261127);
  constexpr int n = 1'000'000;
  std::vector<double> draws(n);
  for (double& d : draws) d = rng.Normal();
  double sum = 0.0, sum2 = 0.0, sum4 = 0.0;
  int tail = 0;
  double tail_excess = 0.0;
  for (double d : draws) {
    sum += d;
    sum2 += d * d;
    sum4 += d * d * d * d;
    if (std::fabs(d) > ZigguratTables::kR) {
      ++tail;
      tail_excess += std::fabs(d) - ZigguratTables::kR;
    }
  }
  // Moments within about four standard errors.
  EXPECT_NEAR(sum / n, 0.0, 4.0 / std::sqrt(n));
  EXPECT_NEAR(sum2 / n, 1.0, 4.0 * std::sqrt(2.0 / n));
  EXPECT_NEAR(sum4 / n, 3.0, 4.0 * std::sqrt(96.0 / n));
  // The tail beyond kR (its own sampler): 2 (1 - Phi(kR)) of the draws, about 576 of a million
  // (Poisson: five standard deviations), and its mean excess phi(R) / (1 - Phi(R)) - R.
  const double r = ZigguratTables::kR;
  const double p_tail = 2.0 * (1.0 - NormalCdf(r));
  EXPECT_NEAR(tail, p_tail * n, 5.0 * std::sqrt(p_tail * n));
  const double phi_r = Density(r) / std::sqrt(2.0 * std::numbers::pi);
  const double mean_excess = phi_r / (1.0 - NormalCdf(r)) - r;
  EXPECT_NEAR(tail_excess / tail, mean_excess, 5.0 * mean_excess / std::sqrt(tail));
  // Kolmogorov-Smirnov against Phi: 1.63 / sqrt(n) is its 1 % critical value.
  std::sort(draws.begin(), draws.end());
  double ks = 0.0;
  for (int i = 0; i < n; ++i) {
    const double cdf = NormalCdf(draws[static_cast<size_t>(i)]);
    ks = std::max({ks, cdf - static_cast<double>(i) / n, static_cast<double>(i + 1) / n - cdf});
  }
  EXPECT_LT(ks, 1.63 / std::sqrt(n));
}

TEST(ZigguratTest, TheWedgesAreDrawnAsTheDensityFalls) {
  // Draws between x[i + 1] and x[i] of the layers come from the wedges' test (about 1 % of
  // all): their share per band of the density must match the normal's, which a wedge accepting
  // every point (a staircase instead of the curve) would not.
  Rng rng(7);
  constexpr int n = 4'000'000;
  const ZigguratTables& z = Ziggurat();
  // Bands [x[i + 1], x[i]) for layers 2 to 40 (x from about 1.7 to 3.2), where most wedges lie.
  int in_band = 0;
  constexpr size_t first = 2, last = 40;
  for (int k = 0; k < n; ++k) {
    const double a = std::fabs(rng.Normal());
    if (a >= z.x[last + 1] && a < z.x[first]) ++in_band;
  }
  const double p = 2.0 * (NormalCdf(z.x[first]) - NormalCdf(z.x[last + 1]));
  EXPECT_NEAR(in_band, p * n, 5.0 * std::sqrt(p * n));
}

TEST(ZigguratTest, SameSeedSameDrawsAndSigmaScales) {
  Rng a(42), b(42);
  for (int i = 0; i < 1000; ++i) {
    const double x = a.Normal();
    EXPECT_EQ(b.Normal(0.25), 0.25 * x);
  }
}

}  // namespace
}  // namespace slam
