#include "scheduler/params_catalog.hpp"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <nlohmann/json.hpp>
#include <string_view>
#include <utility>

#include "engine/io/params_json.hpp"

namespace slam {
namespace detail {
const std::vector<std::pair<long long, std::string_view>>& ShippedParamsTexts();
}  // namespace detail

const std::vector<ParamsSet>& ShippedParams() {
  static const std::vector<ParamsSet> sets = [] {
    std::vector<ParamsSet> out;
    for (const auto& [budget, text] : detail::ShippedParamsTexts()) {
      const std::string name = "shipped-" + std::to_string(budget);
      const auto json = nlohmann::json::parse(text, nullptr, false);
      const Result<SlamParams> params = io::ParamsFromJson(json);
      if (json.is_discarded() || !params.ok()) {
        // A build-time file: the shipped-sets test fails on it long before a user could.
        std::fprintf(stderr, "config/params/%lld.json is invalid: %s\n", budget,
                     json.is_discarded() ? "not JSON" : params.Message().c_str());
        std::abort();
      }
      out.push_back({name, budget, params.value()});
    }
    std::sort(out.begin(), out.end(),
              [](const ParamsSet& a, const ParamsSet& b) { return a.budget < b.budget; });
    if (out.empty()) {
      std::fprintf(stderr, "no parameter set was compiled in (config/params/)\n");
      std::abort();
    }
    return out;
  }();
  return sets;
}

const ParamsSet& ShippedParamsFor(int64_t quota) {
  const std::vector<ParamsSet>& sets = ShippedParams();
  const ParamsSet* chosen = &sets.front();
  for (const ParamsSet& set : sets) {
    if (set.budget <= quota) chosen = &set;
  }
  return *chosen;
}

ParamsChoice::ParamsChoice(std::string name, const SlamParams& params)
    : follows_quota_(false), fixed_{std::move(name), 0, params} {}

const ParamsSet& ParamsChoice::For(int64_t quota) const {
  return follows_quota_ ? ShippedParamsFor(quota) : fixed_;
}

}  // namespace slam
