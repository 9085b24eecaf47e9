#include "offline/statistics.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

namespace slam::offline {
namespace {

// Above this pooled size the exact distribution gives way to the normal approximation; at the
// limit the dynamic programme costs about n^4 / 12 multiply-adds (~2e7, a few milliseconds).
constexpr int64_t kExactLimit = 120;

// Quantile p of sorted values, interpolating linearly between order statistics (type 7).
double Type7Quantile(const std::vector<double>& sorted, double p) {
  const double h = static_cast<double>(sorted.size() - 1) * p;
  const auto lo = static_cast<size_t>(std::floor(h));
  if (lo + 1 >= sorted.size()) return sorted.back();
  return sorted[lo] + (h - static_cast<double>(lo)) * (sorted[lo + 1] - sorted[lo]);
}

// A run of equal values in the pooled, sorted sample.
struct TieGroup {
  int64_t size = 0;          // t
  int64_t from_a = 0;        // how many of them belong to the first sample
  int64_t doubled_rank = 0;  // twice the mid-rank: 2 * (values before) + t + 1
};

std::vector<TieGroup> PoolIntoTieGroups(const std::vector<double>& a,
                                        const std::vector<double>& b) {
  std::vector<std::pair<double, bool>> pooled;  // (value, belongs to a)
  pooled.reserve(a.size() + b.size());
  for (const double v : a) pooled.emplace_back(v, true);
  for (const double v : b) pooled.emplace_back(v, false);
  std::sort(pooled.begin(), pooled.end());
  std::vector<TieGroup> groups;
  int64_t before = 0;
  for (size_t i = 0; i < pooled.size();) {
    TieGroup group;
    size_t j = i;
    for (; j < pooled.size() && pooled[j].first == pooled[i].first; ++j) {
      ++group.size;
      if (pooled[j].second) ++group.from_a;
    }
    group.doubled_rank = 2 * before + group.size + 1;
    before += group.size;
    groups.push_back(group);
    i = j;
  }
  return groups;
}

// Two-sided exact p-value: the null distribution of the doubled rank sum of `k` items drawn from
// the pooled groups, built group by group (choosing j of a group of t in C(t, j) ways), then
// P(|R - E[R]| >= |observed - E[R]|). All sums are integers, so the comparison is exact.
double ExactPValue(const std::vector<TieGroup>& groups, int64_t n, int64_t k,
                   int64_t observed_doubled_sum) {
  // The k largest doubled mid-ranks sum to at most the k largest doubled ranks.
  const int64_t max_sum = k * (2 * n - k + 1);
  const auto width = static_cast<size_t>(max_sum + 1);
  const auto rows = static_cast<size_t>(k + 1);
  // counts[kk * width + s]: ways to pick kk items (so far) whose doubled ranks sum to s.
  std::vector<double> counts(rows * width, 0.0);
  counts[0] = 1.0;
  // Reachable sums of each row, [lo, hi]; empty (lo > hi) while the row is unreachable.
  std::vector<int64_t> lo(rows, std::numeric_limits<int64_t>::max());
  std::vector<int64_t> hi(rows, -1);
  lo[0] = hi[0] = 0;

  std::vector<double> binomial;  // C(t, j), j = 0..t, by Pascal's rule
  int64_t processed = 0;
  int64_t remaining = n;
  for (const TieGroup& group : groups) {
    const int64_t t = group.size;
    const int64_t d = group.doubled_rank;
    binomial.assign(static_cast<size_t>(t + 1), 0.0);
    binomial[0] = 1.0;
    for (int64_t row = 1; row <= t; ++row) {
      for (int64_t j = row; j >= 1; --j) {
        binomial[static_cast<size_t>(j)] += binomial[static_cast<size_t>(j - 1)];
      }
    }
    remaining -= t;
    // Rows below k - remaining can never grow to k items: skip them. Descending kk keeps the
    // update in place, since row kk only reads rows kk - j that this group has not touched yet.
    const int64_t kk_first = std::min(k, processed + t);
    const int64_t kk_last = std::max<int64_t>(1, k - remaining);
    for (int64_t kk = kk_first; kk >= kk_last; --kk) {
      double* target = &counts[static_cast<size_t>(kk) * width];
      int64_t new_lo = lo[static_cast<size_t>(kk)];
      int64_t new_hi = hi[static_cast<size_t>(kk)];
      for (int64_t j = 1; j <= std::min(t, kk); ++j) {
        const auto source_row = static_cast<size_t>(kk - j);
        const int64_t src_lo = lo[source_row];
        const int64_t src_hi = hi[source_row];
        if (src_lo > src_hi) continue;
        const double ways = binomial[static_cast<size_t>(j)];
        const double* source = &counts[source_row * width];
        const int64_t shift = j * d;
        for (int64_t s = src_lo; s <= src_hi; ++s) {
          target[s + shift] += ways * source[s];
        }
        new_lo = std::min(new_lo, src_lo + shift);
        new_hi = std::max(new_hi, src_hi + shift);
      }
      lo[static_cast<size_t>(kk)] = new_lo;
      hi[static_cast<size_t>(kk)] = new_hi;
    }
    processed += t;
  }

  const double* final_row = &counts[static_cast<size_t>(k) * width];
  const int64_t expected = k * (n + 1);  // doubled E[R]
  const int64_t observed_deviation = std::abs(observed_doubled_sum - expected);
  double total = 0.0;
  double tail = 0.0;
  for (int64_t s = lo[static_cast<size_t>(k)]; s <= hi[static_cast<size_t>(k)]; ++s) {
    total += final_row[s];
    if (std::abs(s - expected) >= observed_deviation) tail += final_row[s];
  }
  return std::min(1.0, tail / total);
}

// Two-sided p-value from the normal approximation with tie and continuity corrections.
double NormalPValue(const std::vector<TieGroup>& groups, int64_t n_a, int64_t n_b, double u) {
  if (groups.size() == 1) return 1.0;  // all values tied: sigma = 0, no evidence either way
  const auto n = static_cast<double>(n_a + n_b);
  double tie_sum = 0.0;  // sum of t^3 - t
  for (const TieGroup& group : groups) {
    const auto t = static_cast<double>(group.size);
    tie_sum += t * t * t - t;
  }
  const double product = static_cast<double>(n_a) * static_cast<double>(n_b);
  const double variance = product / 12.0 * ((n + 1.0) - tie_sum / (n * (n - 1.0)));
  // Clamped at zero so that U at its mean gives p = 1 (as SciPy does), not slightly less.
  const double numerator = std::max(0.0, std::abs(u - product / 2.0) - 0.5);
  const double z = numerator / std::sqrt(variance);
  return std::min(1.0, std::erfc(z / std::sqrt(2.0)));
}

}  // namespace

FiveNumbers SummarizeFive(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  FiveNumbers five;
  five.min = values.front();
  five.q1 = Type7Quantile(values, 0.25);
  five.median = Type7Quantile(values, 0.5);
  five.q3 = Type7Quantile(values, 0.75);
  five.max = values.back();
  return five;
}

MannWhitneyResult MannWhitneyU(const std::vector<double>& a, const std::vector<double>& b) {
  const auto n_a = static_cast<int64_t>(a.size());
  const auto n_b = static_cast<int64_t>(b.size());
  const int64_t n = n_a + n_b;
  const std::vector<TieGroup> groups = PoolIntoTieGroups(a, b);
  int64_t doubled_sum_a = 0;
  for (const TieGroup& group : groups) doubled_sum_a += group.from_a * group.doubled_rank;

  MannWhitneyResult result;
  result.u = static_cast<double>(doubled_sum_a - n_a * (n_a + 1)) / 2.0;
  if (n <= kExactLimit) {
    // The two rank sums add to a constant, so their deviations are equal: run the programme on
    // the smaller sample, which keeps it at most n / 2 rows tall.
    const bool a_smaller = n_a <= n_b;
    const int64_t doubled_sum_b = n * (n + 1) - doubled_sum_a;
    result.p_value =
        ExactPValue(groups, n, a_smaller ? n_a : n_b, a_smaller ? doubled_sum_a : doubled_sum_b);
    result.exact = true;
  } else {
    result.p_value = NormalPValue(groups, n_a, n_b, result.u);
  }
  return result;
}

double NormalQuantile(double p) {
  double lo = -40.0, hi = 40.0;
  while (hi - lo > 1e-12) {
    const double mid = 0.5 * (lo + hi);
    (0.5 * std::erfc(-mid / std::sqrt(2.0)) < p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace slam::offline
