#pragma once
// Order statistics and the Mann-Whitney U test, for the tuner's per-generation summaries
// (paper Fig. 10) and its comparison of budgets (paper Table III).

#include <vector>

namespace slam::offline {

/// Minimum, quartiles, median and maximum of a sample.
struct FiveNumbers {
  double min = 0, q1 = 0, median = 0, q3 = 0, max = 0;
};

/// Five-number summary with quantiles by linear interpolation between order statistics
/// (the "type 7" definition of R and NumPy's default). Precondition: values not empty, no NaN.
FiveNumbers SummarizeFive(std::vector<double> values);

struct MannWhitneyResult {
  double u = 0;        // U of the first sample: pairs (a, b) with a > b, ties counting 1/2
  double p_value = 1;  // two-sided
  bool exact = false;  // exact permutation distribution (true) or normal approximation
};

/// Two-sided Mann-Whitney U test of `a` against `b`. Exact permutation distribution of the rank
/// sum, ties included (mid-ranks), when the samples are small enough (n_a + n_b <= 120);
/// otherwise the normal approximation with tie correction and continuity correction.
/// Preconditions: both samples non-empty, no NaN.
MannWhitneyResult MannWhitneyU(const std::vector<double>& a, const std::vector<double>& b);

/// The standard normal distribution's quantile: the z with P(Z <= z) = p, for p in (0, 1)
/// (bisection on erfc, to within 1e-12).
double NormalQuantile(double p);

}  // namespace slam::offline
