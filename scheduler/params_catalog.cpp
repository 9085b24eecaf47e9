#include "scheduler/params_catalog.hpp"

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstdlib>
#include <nlohmann/json.hpp>
#include <string_view>
#include <utility>

#include "engine/io/params_json.hpp"

namespace slam {
namespace detail {
struct ShippedParamsText {
  int family;  // ParamsFamily
  long long budget;
  std::string_view text;
};
const std::vector<ShippedParamsText>& ShippedParamsTexts();
}  // namespace detail

namespace {

constexpr std::array<const char*, 2> kFamilyDirs{"config/params/", "config/params/laser/"};
constexpr std::array<const char*, 2> kFamilyPrefixes{"shipped-", "shipped-laser-"};

std::vector<ParamsSet> LoadFamily(ParamsFamily family) {
  const auto index = static_cast<size_t>(family);
  std::vector<ParamsSet> out;
  for (const detail::ShippedParamsText& shipped : detail::ShippedParamsTexts()) {
    if (shipped.family != static_cast<int>(family)) continue;
    const std::string name = kFamilyPrefixes[index] + std::to_string(shipped.budget);
    const auto json = nlohmann::json::parse(shipped.text, nullptr, false);
    const Result<SlamParams> params = io::ParamsFromJson(json);
    if (json.is_discarded() || !params.ok()) {
      // A build-time file: the shipped-sets test fails on it long before a user could.
      std::fprintf(stderr, "%s%lld.json is invalid: %s\n", kFamilyDirs[index], shipped.budget,
                   json.is_discarded() ? "not JSON" : params.Message().c_str());
      std::abort();
    }
    out.push_back({name, shipped.budget, params.value()});
  }
  std::sort(out.begin(), out.end(),
            [](const ParamsSet& a, const ParamsSet& b) { return a.budget < b.budget; });
  if (out.empty()) {
    std::fprintf(stderr, "no parameter set was compiled in (%s)\n", kFamilyDirs[index]);
    std::abort();
  }
  return out;
}

}  // namespace

ParamsFamily FamilyOf(const RobotDescription& robot) {
  return HasRangeScanner(robot) ? ParamsFamily::kRange : ParamsFamily::kInfrared;
}

const std::vector<ParamsSet>& ShippedParams(ParamsFamily family) {
  if (family == ParamsFamily::kRange) {
    static const std::vector<ParamsSet> range = LoadFamily(ParamsFamily::kRange);
    return range;
  }
  static const std::vector<ParamsSet> infrared = LoadFamily(ParamsFamily::kInfrared);
  return infrared;
}

const ParamsSet& ShippedParamsFor(int64_t quota, ParamsFamily family) {
  const std::vector<ParamsSet>& sets = ShippedParams(family);
  const ParamsSet* chosen = &sets.front();
  for (const ParamsSet& set : sets) {
    if (set.budget <= quota) chosen = &set;
  }
  return *chosen;
}

ParamsChoice::ParamsChoice(std::string name, const SlamParams& params)
    : follows_quota_(false), fixed_{std::move(name), 0, params} {}

const ParamsSet& ParamsChoice::For(int64_t quota) const {
  return follows_quota_ ? ShippedParamsFor(quota, family_) : fixed_;
}

}  // namespace slam
