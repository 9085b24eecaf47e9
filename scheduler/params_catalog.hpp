#pragma once
// Which SLAM parameters a scan runs with: the sets shipped in config/params/<budget>.json (one per
// paper budget, chosen on the validation worlds among slam-tune's best and the Table II defaults:
// docs/accuracy.md; compiled in), picked by the scan's quota, or one set given by the user
// (--params, PATCH /api/v1/params) that holds whatever the quota.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "engine/params.hpp"

namespace slam {

/// One named set of parameters.
struct ParamsSet {
  std::string name;    // "shipped-8125" for a shipped set, else what the user gave (a path)
  int64_t budget = 0;  // the rays per scan it was chosen for; 0 for a user's set
  SlamParams params;

  friend bool operator==(const ParamsSet&, const ParamsSet&) = default;
};

/// The shipped sets, by increasing budget (config/params/, embedded at build time). Never empty.
const std::vector<ParamsSet>& ShippedParams();

/// The set for a scan whose quota is `quota` rays: the shipped set of the largest budget not
/// above the quota, the smallest budget's set below them all. In rays-per-scan mode the quota is
/// the budget, so `--budget 8125` runs shipped-8125 and `--budget 20000` runs shipped-16250.
const ParamsSet& ShippedParamsFor(int64_t quota);

/// How a run picks its parameters: the shipped sets by quota, or one fixed set.
class ParamsChoice {
 public:
  /// The shipped sets, chosen by quota.
  ParamsChoice() = default;
  /// One set, whatever the quota.
  ParamsChoice(std::string name, const SlamParams& params);

  bool follows_quota() const { return follows_quota_; }
  /// The set for a scan with this quota.
  const ParamsSet& For(int64_t quota) const;

 private:
  bool follows_quota_ = true;
  ParamsSet fixed_;
};

}  // namespace slam
