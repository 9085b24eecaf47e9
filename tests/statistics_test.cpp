#include "offline/statistics.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <utility>
#include <vector>

#include "engine/random.hpp"

namespace slam {
namespace {

// Twice the U statistic of `a`: 2 per pair a > b, 1 per tie (integer, so exact).
int64_t DoubledU(const std::vector<double>& a, const std::vector<double>& b) {
  int64_t u = 0;
  for (const double x : a) {
    for (const double y : b) u += x > y ? 2 : (x == y ? 1 : 0);
  }
  return u;
}

// Oracle: the two-sided p-value by enumerating every way to deal the pooled values into samples
// of sizes n_a and n_b (pooled size at most ~16).
double BruteForcePValue(const std::vector<double>& a, const std::vector<double>& b) {
  std::vector<double> pooled = a;
  pooled.insert(pooled.end(), b.begin(), b.end());
  const int n = static_cast<int>(pooled.size());
  const auto n_a = static_cast<int>(a.size());
  const int64_t doubled_mean = static_cast<int64_t>(a.size() * b.size());  // 2 * n_a n_b / 2
  const int64_t observed = std::abs(DoubledU(a, b) - doubled_mean);
  int64_t total = 0;
  int64_t extreme = 0;
  for (uint32_t mask = 0; mask < (1u << n); ++mask) {
    if (std::popcount(mask) != n_a) continue;
    std::vector<double> first;
    std::vector<double> second;
    for (int i = 0; i < n; ++i) {
      ((mask >> i) & 1u ? first : second).push_back(pooled[static_cast<size_t>(i)]);
    }
    ++total;
    if (std::abs(DoubledU(first, second) - doubled_mean) >= observed) ++extreme;
  }
  return static_cast<double>(extreme) / static_cast<double>(total);
}

// A sample of `size` values drawn from {0, ..., levels - 1}, so that ties are frequent.
std::vector<double> TiedSample(Rng& rng, int size, int levels) {
  std::vector<double> values;
  for (int i = 0; i < size; ++i) values.push_back(std::floor(rng.Uniform() * levels));
  return values;
}

// Two samples of 8 without ties whose U (of the first) is `u`: b = 1..8, and each a_i sits above
// c_i of the b's, the c_i filled from the largest a down.
void EightByEightWithU(int u, std::vector<double>& a, std::vector<double>& b) {
  a.assign(8, 0.0);
  b.clear();
  for (int i = 1; i <= 8; ++i) b.push_back(i);
  int remaining = u;
  for (int i = 7; i >= 0; --i) {
    const int below = std::min(8, remaining);
    remaining -= below;
    a[static_cast<size_t>(i)] = below + 0.5 + 0.01 * i;  // distinct, so no ties among the a's
  }
}

// Oracle for the normal approximation: tie-corrected sigma, continuity correction, from the raw
// samples.
double NormalPValueOracle(const std::vector<double>& a, const std::vector<double>& b) {
  std::vector<double> pooled = a;
  pooled.insert(pooled.end(), b.begin(), b.end());
  std::sort(pooled.begin(), pooled.end());
  double tie_sum = 0.0;
  for (size_t i = 0; i < pooled.size();) {
    size_t j = i;
    while (j < pooled.size() && pooled[j] == pooled[i]) ++j;
    const auto t = static_cast<double>(j - i);
    tie_sum += t * t * t - t;
    i = j;
  }
  const auto n_a = static_cast<double>(a.size());
  const auto n_b = static_cast<double>(b.size());
  const double n = n_a + n_b;
  const double sigma = std::sqrt(n_a * n_b / 12.0 * ((n + 1.0) - tie_sum / (n * (n - 1.0))));
  const double u = static_cast<double>(DoubledU(a, b)) / 2.0;
  const double z = (std::abs(u - n_a * n_b / 2.0) - 0.5) / sigma;
  return std::erfc(z / std::sqrt(2.0));
}

TEST(SummarizeFive, OneElement) {
  const offline::FiveNumbers five = offline::SummarizeFive({7.0});
  EXPECT_EQ(five.min, 7.0);
  EXPECT_EQ(five.q1, 7.0);
  EXPECT_EQ(five.median, 7.0);
  EXPECT_EQ(five.q3, 7.0);
  EXPECT_EQ(five.max, 7.0);
}

TEST(SummarizeFive, OddSizeUnsorted) {
  // Sorted: 1 3 4 8 10 15 21 (n = 7). Type 7: h = (n - 1) p.
  // q1: h = 1.5 -> 3 + 0.5 * (4 - 3) = 3.5; median: h = 3 -> 8; q3: h = 4.5 -> 10 + 0.5 * 5 = 12.5.
  const offline::FiveNumbers five = offline::SummarizeFive({15, 1, 21, 8, 3, 10, 4});
  EXPECT_DOUBLE_EQ(five.min, 1.0);
  EXPECT_DOUBLE_EQ(five.q1, 3.5);
  EXPECT_DOUBLE_EQ(five.median, 8.0);
  EXPECT_DOUBLE_EQ(five.q3, 12.5);
  EXPECT_DOUBLE_EQ(five.max, 21.0);
}

TEST(SummarizeFive, EvenSize) {
  // 1 2 3 4: q1 h = 0.75 -> 1.75; median h = 1.5 -> 2.5; q3 h = 2.25 -> 3.25.
  const offline::FiveNumbers five = offline::SummarizeFive({4, 3, 2, 1});
  EXPECT_DOUBLE_EQ(five.min, 1.0);
  EXPECT_DOUBLE_EQ(five.q1, 1.75);
  EXPECT_DOUBLE_EQ(five.median, 2.5);
  EXPECT_DOUBLE_EQ(five.q3, 3.25);
  EXPECT_DOUBLE_EQ(five.max, 4.0);
}

TEST(SummarizeFive, DuplicatesUnsorted) {
  // Sorted: 1 2 4 4 4 9 (n = 6). q1: h = 1.25 -> 2 + 0.25 * (4 - 2) = 2.5;
  // median: h = 2.5 -> 4 + 0.5 * 0 = 4; q3: h = 3.75 -> 4 + 0.75 * 0 = 4.
  const offline::FiveNumbers five = offline::SummarizeFive({4, 1, 4, 9, 2, 4});
  EXPECT_DOUBLE_EQ(five.min, 1.0);
  EXPECT_DOUBLE_EQ(five.q1, 2.5);
  EXPECT_DOUBLE_EQ(five.median, 4.0);
  EXPECT_DOUBLE_EQ(five.q3, 4.0);
  EXPECT_DOUBLE_EQ(five.max, 9.0);
}

TEST(SummarizeFive, TenValuesWithFractionalPositions) {
  // 0 2 4 ... 18 (n = 10). q1: h = 2.25 -> 4.5; median: h = 4.5 -> 9; q3: h = 6.75 -> 13.5.
  const offline::FiveNumbers five = offline::SummarizeFive({18, 0, 16, 2, 14, 4, 12, 6, 10, 8});
  EXPECT_DOUBLE_EQ(five.q1, 4.5);
  EXPECT_DOUBLE_EQ(five.median, 9.0);
  EXPECT_DOUBLE_EQ(five.q3, 13.5);
}

TEST(MannWhitney, SeparatedSamplesOfThree) {
  // The 20 arrangements of 3 + 3 values: only "all a below" and "all a above" are as extreme.
  const offline::MannWhitneyResult low = offline::MannWhitneyU({1, 2, 3}, {4, 5, 6});
  EXPECT_TRUE(low.exact);
  EXPECT_EQ(low.u, 0.0);
  EXPECT_NEAR(low.p_value, 2.0 / 20.0, 1e-15);
  const offline::MannWhitneyResult high = offline::MannWhitneyU({4, 5, 6}, {1, 2, 3});
  EXPECT_EQ(high.u, 9.0);
  EXPECT_NEAR(high.p_value, 2.0 / 20.0, 1e-15);
}

TEST(MannWhitney, SeparatedSamplesOfFourAndFive) {
  // C(9, 4) = 126 arrangements, two as extreme as complete separation.
  const offline::MannWhitneyResult result = offline::MannWhitneyU({1, 2, 3, 4}, {5, 6, 7, 8, 9});
  EXPECT_EQ(result.u, 0.0);
  EXPECT_NEAR(result.p_value, 2.0 / 126.0, 1e-15);
}

TEST(MannWhitney, IdenticalSamplesGiveOne) {
  const offline::MannWhitneyResult same = offline::MannWhitneyU({1, 2, 3}, {1, 2, 3});
  EXPECT_EQ(same.u, 4.5);  // 3 pairs a > b + 3 ties / 2
  EXPECT_DOUBLE_EQ(same.p_value, 1.0);
  const offline::MannWhitneyResult all_tied = offline::MannWhitneyU({5, 5}, {5, 5, 5});
  EXPECT_TRUE(all_tied.exact);
  EXPECT_EQ(all_tied.u, 3.0);
  EXPECT_DOUBLE_EQ(all_tied.p_value, 1.0);
}

TEST(MannWhitney, HandEnumeratedTies) {
  // a = {1, 2, 2}, b = {2, 3}: pooled mid-ranks 1, 3, 3, 3, 5; U = 0.5 + 0.5 = 1, E[U] = 3.
  // The C(5, 3) = 10 choices for a, by rank multiset:
  //   {1,3,3} 3 ways, U = 1 | {1,3,5} 3 ways, U = 3 | {3,3,3} 1 way, U = 3 | {3,3,5} 3 ways, U = 5
  // |U - 3| >= 2 in 3 + 3 of them: p = 6/10.
  const offline::MannWhitneyResult result = offline::MannWhitneyU({1, 2, 2}, {2, 3});
  EXPECT_EQ(result.u, 1.0);
  EXPECT_NEAR(result.p_value, 0.6, 1e-15);
}

TEST(MannWhitney, MatchesBruteForceOnRandomTiedSamples) {
  Rng rng(20240611);
  for (int trial = 0; trial < 300; ++trial) {
    const int n_a = 1 + static_cast<int>(rng.Uniform() * 7);
    const int n_b = 1 + static_cast<int>(rng.Uniform() * 7);
    const int levels = 2 + static_cast<int>(rng.Uniform() * 5);
    const std::vector<double> a = TiedSample(rng, n_a, levels);
    const std::vector<double> b = TiedSample(rng, n_b, levels);
    const offline::MannWhitneyResult result = offline::MannWhitneyU(a, b);
    ASSERT_TRUE(result.exact);
    ASSERT_EQ(2.0 * result.u, static_cast<double>(DoubledU(a, b))) << "trial " << trial;
    ASSERT_NEAR(result.p_value, BruteForcePValue(a, b), 1e-12) << "trial " << trial;
  }
}

TEST(MannWhitney, SymmetricInSampleOrder) {
  Rng rng(7);
  // Sizes on both paths: exact (pooled <= 120) and normal.
  for (const int size : {5, 12, 48, 60, 61, 90}) {
    const std::vector<double> a = TiedSample(rng, size, 6);
    const std::vector<double> b = TiedSample(rng, size + 3 * (size % 2), 6);
    const offline::MannWhitneyResult ab = offline::MannWhitneyU(a, b);
    const offline::MannWhitneyResult ba = offline::MannWhitneyU(b, a);
    EXPECT_EQ(ab.u + ba.u, static_cast<double>(a.size() * b.size())) << size;
    EXPECT_NEAR(ab.p_value, ba.p_value, 1e-12) << size;
    EXPECT_EQ(ab.exact, ba.exact);
  }
}

TEST(MannWhitney, CriticalValueTableEightByEight) {
  // Published tables give 13 as the two-sided 0.05 critical U for n1 = n2 = 8. Counting
  // arrangements (Gaussian binomial coefficients): 321 of C(16, 8) = 12870 have U <= 13 and 418
  // have U <= 14, so p(13) = 642 / 12870 = 0.04988 and p(14) = 836 / 12870 = 0.06496.
  std::vector<double> a;
  std::vector<double> b;
  EightByEightWithU(13, a, b);
  const offline::MannWhitneyResult at_critical = offline::MannWhitneyU(a, b);
  EXPECT_EQ(at_critical.u, 13.0);
  EXPECT_LE(at_critical.p_value, 0.05);
  EXPECT_NEAR(at_critical.p_value, 642.0 / 12870.0, 1e-14);
  EightByEightWithU(14, a, b);
  const offline::MannWhitneyResult above = offline::MannWhitneyU(a, b);
  EXPECT_EQ(above.u, 14.0);
  EXPECT_GT(above.p_value, 0.05);
  EXPECT_NEAR(above.p_value, 836.0 / 12870.0, 1e-14);
  // The mirror image (U = 64 - 13 = 51) is as extreme.
  EightByEightWithU(13, a, b);
  EXPECT_NEAR(offline::MannWhitneyU(b, a).p_value, 642.0 / 12870.0, 1e-14);
}

TEST(MannWhitney, ExactTailAtTheLimitIsAccurate) {
  // 60 + 60 values with complete separation: 2 of C(120, 60) ~ 9.66e34 arrangements.
  std::vector<double> a;
  std::vector<double> b;
  for (int i = 0; i < 60; ++i) {
    a.push_back(i);
    b.push_back(60 + i);
  }
  double choose = 1.0;  // C(120, 60)
  for (int i = 1; i <= 60; ++i) choose = choose * (60.0 + i) / i;
  const offline::MannWhitneyResult separated = offline::MannWhitneyU(a, b);
  EXPECT_TRUE(separated.exact);
  EXPECT_NEAR(separated.p_value / (2.0 / choose), 1.0, 1e-12);
  // Swap the largest a with the smallest b: U = 1, and U <= 1 happens in 2 arrangements per tail.
  std::swap(a.back(), b.front());
  const offline::MannWhitneyResult one_swap = offline::MannWhitneyU(a, b);
  EXPECT_EQ(one_swap.u, 1.0);
  EXPECT_NEAR(one_swap.p_value / (4.0 / choose), 1.0, 1e-12);
}

TEST(MannWhitney, ExactAgreesWithNormalNearTheLimit) {
  // a = 0..59, b = 5.5..64.5: a_i > b_j iff i >= j + 6, so U = sum_{j=0}^{53} (54 - j) = 1485.
  // Exact p = 2 P(U <= 1485) = 0.0989188122061937 (Gaussian binomial coefficients, Python);
  // normal: sigma = sqrt(3600 * 121 / 12) = 190.526, z = 314.5 / sigma = 1.6507, p = 0.098800.
  std::vector<double> a;
  std::vector<double> b;
  for (int i = 0; i < 60; ++i) {
    a.push_back(i);
    b.push_back(i + 5.5);
  }
  const offline::MannWhitneyResult result = offline::MannWhitneyU(a, b);
  EXPECT_TRUE(result.exact);
  EXPECT_EQ(result.u, 1485.0);
  EXPECT_NEAR(result.p_value, 0.0989188122061937, 1e-12);
  EXPECT_NEAR(result.p_value, NormalPValueOracle(a, b), 0.01);
  // One more value crosses the limit to the normal approximation.
  b.push_back(65.5);
  EXPECT_FALSE(offline::MannWhitneyU(a, b).exact);
}

TEST(MannWhitney, NormalApproximationWithTiesByHand) {
  // a: 40 zeros, 30 ones (n_a = 70); b: 20 zeros, 40 ones (n_b = 60); n = 130 > 120.
  // U = 30 * 20 (a = 1 > b = 0) + (40 * 20 + 30 * 40) / 2 = 1600; E[U] = 70 * 60 / 2 = 2100.
  // Ties: 60 zeros, 70 ones: sum(t^3 - t) = 215940 + 342930 = 558870; n (n - 1) = 16770.
  // sigma^2 = 4200 / 12 * (131 - 558870 / 16770) = 350 * 97.674419 = 34186.0465, sigma = 184.8947.
  // z = (500 - 0.5) / 184.8947 = 2.701538; p = erfc(z / sqrt 2) = 0.0069020.
  std::vector<double> a(70, 0.0);
  std::fill(a.begin() + 40, a.end(), 1.0);
  std::vector<double> b(60, 0.0);
  std::fill(b.begin() + 20, b.end(), 1.0);
  const offline::MannWhitneyResult result = offline::MannWhitneyU(a, b);
  EXPECT_FALSE(result.exact);
  EXPECT_EQ(result.u, 1600.0);
  EXPECT_NEAR(result.p_value, 0.0069020, 1e-6);
}

TEST(MannWhitney, NormalApproximationAllTiedGivesOne) {
  const offline::MannWhitneyResult result =
      offline::MannWhitneyU(std::vector<double>(70, 2.0), std::vector<double>(60, 2.0));
  EXPECT_FALSE(result.exact);
  EXPECT_EQ(result.u, 2100.0);
  EXPECT_EQ(result.p_value, 1.0);
}

TEST(MannWhitney, FortyEightEachWithHeavyTies) {
  // The tuner's case: 48 runs per budget, scores on a coarse grid.
  Rng rng(48);
  const std::vector<double> a = TiedSample(rng, 48, 4);
  std::vector<double> b = TiedSample(rng, 48, 4);
  for (double& v : b) v = std::min(3.0, v + (rng.Uniform() < 0.3 ? 1.0 : 0.0));
  const offline::MannWhitneyResult result = offline::MannWhitneyU(a, b);
  EXPECT_TRUE(result.exact);
  EXPECT_GT(result.p_value, 0.0);
  EXPECT_LE(result.p_value, 1.0);
  // The tie-corrected normal approximation is close at this size.
  EXPECT_NEAR(result.p_value, NormalPValueOracle(a, b), 0.02);
}

}  // namespace
}  // namespace slam
