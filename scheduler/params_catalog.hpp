#pragma once
// Which SLAM parameters a scan runs with: the sets shipped in config/params/ (one per paper budget
// and scanner family, compiled in: config/params/<budget>.json for the marXbot's infrared
// scanner, chosen on the validation worlds among slam-tune's best and the Table II defaults,
// docs/accuracy.md; config/params/laser/<budget>.json for range scanners, tuned on simulated
// laser experiments, docs/laser.md), picked by the scan's quota and the robot's scanner, or one
// set given by the user (--params, PATCH /api/v1/params) that holds whatever the quota.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "engine/params.hpp"
#include "engine/robot.hpp"

namespace slam {

/// Which shipped family suits a scanner: their motion and matching differ (a laser sees tens of
/// metres at once, a few times a second; the marXbot's four infrared sensors see 1.5 m).
enum class ParamsFamily {
  kInfrared,  // config/params/<budget>.json
  kRange,     // config/params/laser/<budget>.json
};

/// The family of the robot's scanner (kRange when it reports ranges: HasRangeScanner).
ParamsFamily FamilyOf(const RobotDescription& robot);

/// One named set of parameters.
struct ParamsSet {
  std::string name;    // "shipped-8125" or "shipped-laser-8125" for a shipped set, else what the
                       // user gave (a path)
  int64_t budget = 0;  // the rays per scan it was chosen for; 0 for a user's set
  SlamParams params;

  friend bool operator==(const ParamsSet&, const ParamsSet&) = default;
};

/// A family's shipped sets, by increasing budget (embedded at build time). Never empty.
const std::vector<ParamsSet>& ShippedParams(ParamsFamily family = ParamsFamily::kInfrared);

/// The set for a scan whose quota is `quota` rays: the family's shipped set of the largest budget
/// not above the quota, the smallest budget's set below them all. In rays-per-scan mode the quota
/// is the budget, so `--budget 8125` runs shipped-8125 and `--budget 20000` runs shipped-16250.
const ParamsSet& ShippedParamsFor(int64_t quota, ParamsFamily family = ParamsFamily::kInfrared);

/// How a run picks its parameters: a family's shipped sets by quota, or one fixed set.
class ParamsChoice {
 public:
  /// The infrared family's shipped sets, chosen by quota.
  ParamsChoice() = default;
  /// A family's shipped sets, chosen by quota.
  explicit ParamsChoice(ParamsFamily family) : family_(family) {}
  /// One set, whatever the quota.
  ParamsChoice(std::string name, const SlamParams& params);

  bool follows_quota() const { return follows_quota_; }
  ParamsFamily family() const { return family_; }
  /// The set for a scan with this quota.
  const ParamsSet& For(int64_t quota) const;
  /// This choice for a robot: the shipped sets of its scanner's family, or the fixed set as it is.
  ParamsChoice ForRobot(const RobotDescription& robot) const {
    return follows_quota_ ? ParamsChoice(FamilyOf(robot)) : *this;
  }

 private:
  bool follows_quota_ = true;
  ParamsFamily family_ = ParamsFamily::kInfrared;
  ParamsSet fixed_;
};

}  // namespace slam
